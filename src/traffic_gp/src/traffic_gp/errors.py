"""Errors of the traffic_gp package: one base error, a few specific ones.

`TrafficError` derives from `robot_common.errors.WorkspaceError` (the workspace's one root); a bad
parameter or option is the workspace's `robot_common.errors.ConfigError`; `NotFittedError` also
derives from `robot_common.errors.NotFittedError`, so callers may catch either.
"""
from robot_common.errors import NotFittedError as CommonNotFittedError
from robot_common.errors import WorkspaceError


class TrafficError(WorkspaceError, RuntimeError):
    """Base error of traffic_gp."""


class ObservationError(TrafficError, ValueError):
    """Observations are malformed: wrong shapes, negative counts, non-positive exposure, NaN."""


class NotFittedError(TrafficError, CommonNotFittedError):
    """A model was asked to predict or save before it was fitted."""


class ModelFormatError(TrafficError):
    """A saved model file is missing, unreadable, of another format version or another structure."""
