"""People traffic: sparse variational GP regression of people counts over space and time of day.

Importing this package does not import TensorFlow; the first fit, load or prediction does.
"""
from traffic_gp.baselines import BinnedMean, FreMEn
from traffic_gp.errors import ModelFormatError, NotFittedError, ObservationError, TrafficError
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.queries import CrowdQueries

__all__ = [
    "BinnedMean",
    "CrowdQueries",
    "FreMEn",
    "ModelFormatError",
    "NotFittedError",
    "Observations",
    "ObservationError",
    "TrafficError",
    "TrafficGP",
]
