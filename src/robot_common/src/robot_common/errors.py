"""Errors of the shared vocabulary; every workspace package derives its own from these where they
mean the same thing (a bad map, a bad parameter, a model used before it was fitted)."""

__all__ = ["CommonError", "MapError", "ModelError", "TaskError", "ConfigError", "NotFittedError"]


class CommonError(ValueError):
    """Base error of robot_common."""


class MapError(CommonError):
    """A map file, map array or cell grid is missing, unreadable or malformed."""


class ModelError(CommonError):
    """The unicycle model got limits, a time step, states or actions it cannot use."""


class TaskError(CommonError):
    """A navigation task (goal, obstacle, arena, start ranges) is malformed."""


class ConfigError(CommonError):
    """A node parameter is unknown or has a bad value (the node exits with one readable line)."""


class NotFittedError(CommonError):
    """An estimator was asked to predict, score or save before it was fitted.

    Each package's estimators raise a subclass that also derives from the package's own base
    error, so callers may catch either."""
