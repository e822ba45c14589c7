"""Errors of the ros_harness layer."""
from robot_common.errors import WorkspaceError


class HarnessError(WorkspaceError, RuntimeError):
    """A process could not be started, found or queried."""


class ProcessDied(HarnessError):
    """A managed process exited while something waited on it; the message quotes its log."""
