"""Errors of the traffic_gp package."""


class TrafficError(RuntimeError):
    """Base error of traffic_gp."""


class ObservationError(TrafficError, ValueError):
    """Observations are malformed: wrong shapes, negative counts, non-positive exposure, NaN."""


class NotFittedError(TrafficError):
    """A model was asked to predict or save before it was fitted."""


class ModelFormatError(TrafficError):
    """A saved model file is missing, unreadable, of another format version or another structure."""


class ConfigError(TrafficError, ValueError):
    """A hyperparameter or option is out of range."""
