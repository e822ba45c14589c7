"""Errors of the ros_harness layer."""


class HarnessError(RuntimeError):
    """A process could not be started, found or queried."""


class ProcessDied(HarnessError):
    """A managed process exited while something waited on it; the message quotes its log."""
