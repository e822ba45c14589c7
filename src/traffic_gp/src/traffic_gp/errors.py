"""Errors of the traffic_gp package: one base error, a few specific ones.

`NotFittedError` also derives from `robot_common.errors.NotFittedError` (the workspace's one "not
fitted" convention), so callers may catch either.
"""
from robot_common.errors import NotFittedError as CommonNotFittedError


class TrafficError(RuntimeError):
    """Base error of traffic_gp."""


class ObservationError(TrafficError, ValueError):
    """Observations are malformed: wrong shapes, negative counts, non-positive exposure, NaN."""


class NotFittedError(TrafficError, CommonNotFittedError):
    """A model was asked to predict or save before it was fitted."""


class ModelFormatError(TrafficError):
    """A saved model file is missing, unreadable, of another format version or another structure."""


class ConfigError(TrafficError, ValueError):
    """A hyperparameter or option is out of range."""
