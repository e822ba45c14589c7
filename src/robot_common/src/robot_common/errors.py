"""Errors of the workspace: one root, and the shared kinds every package reuses.

Every package's own base error derives from `WorkspaceError`, so a caller can catch all errors
the workspace raises on purpose with one class. Errors that mean the same thing everywhere live
here once: a bad node parameter is always a `ConfigError`, an estimator used before it was fitted
raises a subclass of `NotFittedError` (which also derives from its package's base, so callers may
catch either).
"""

__all__ = ["WorkspaceError", "CommonError", "MapError", "ModelError", "TaskError", "ConfigError",
           "NotFittedError"]


class WorkspaceError(Exception):
    """Root of every error the workspace's packages raise on purpose."""


class CommonError(WorkspaceError, ValueError):
    """Base error of robot_common (bad input to the shared vocabulary)."""


class MapError(CommonError):
    """A map file, map array or cell grid is missing, unreadable or malformed."""


class ModelError(CommonError):
    """The unicycle model got limits, a time step, states or actions it cannot use."""


class TaskError(CommonError):
    """A navigation task (goal, obstacle, arena, start ranges) is malformed."""


class ConfigError(CommonError):
    """A node parameter is unknown or has a bad value (the node exits with one readable line).

    The one configuration error of the workspace: packages raise it (or a subclass) rather than
    defining their own."""


class NotFittedError(CommonError):
    """An estimator was asked to predict, score or save before it was fitted.

    Each package's estimators raise a subclass that also derives from the package's own base
    error, so callers may catch either."""
