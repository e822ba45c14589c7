"""Errors of the robot_sim package (map, task and model errors are robot_common's)."""


class SimError(RuntimeError):
    """Base error of the simulators."""
