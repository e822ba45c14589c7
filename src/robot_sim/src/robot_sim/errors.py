"""Errors of the robot_sim package."""


class SimError(RuntimeError):
    """Base error of the simulators."""


class MapError(SimError):
    """A map file or map array is missing, unreadable or malformed."""
