"""People traffic: sparse variational GP regression of people counts over space and time of day.

Importing this package does not import TensorFlow; the first fit, load or prediction does. The
names below are imported on first use (SciPy's statistics with them), so that a node which only
needs the package's messages, services or parameters (errand_nav's errand server, the people
counter) does not pay for the model's imports.
"""
import importlib

_EXPORTS = {
    "BinnedMean": "traffic_gp.baselines",
    "CrowdQueries": "traffic_gp.queries",
    "FreMEn": "traffic_gp.baselines",
    "ModelFormatError": "traffic_gp.errors",
    "NotFittedError": "traffic_gp.errors",
    "Observations": "traffic_gp.observations",
    "ObservationError": "traffic_gp.errors",
    "TrafficError": "traffic_gp.errors",
    "TrafficGP": "traffic_gp.model",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
