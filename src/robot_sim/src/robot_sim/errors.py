"""Errors of the robot_sim package (map, task and model errors are robot_common's)."""
from robot_common.errors import WorkspaceError


class SimError(WorkspaceError, RuntimeError):
    """Base error of the simulators."""
