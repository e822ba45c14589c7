"""The crowd-model file format, read and written with NumPy only: one `.npz` file, versioned.

A file holds a JSON header (`format`, `format_version`, then whatever the estimator records: its
parameters, training statistics, library versions, caller metadata such as the map it was
trained on), a set of named arrays (the GP parameters in unconstrained form, so that a loaded
model predicts bit for bit what the saved one did), the arrays of the spatial inputs when the
model has map-aware ones (`geodesic.GeodesicEmbedding.to_arrays`), the arrays of its rate profile
(the GP's per-place offset, `rate_profile.RateProfile.to_arrays`) if it has one and, optionally, the arrays of
what it serves besides the GP (`serving.Serving.to_arrays`: the places, the per-place choice,
the baselines) if any and, optionally, the training rows (so `partial_fit` can continue after
loading). This module knows the layout, not the estimators:
`TrafficGP.save` / `TrafficGP.load` and `PosteriorSnapshot.load` decide what goes in and what
comes out. Files are written to a temporary name and renamed: a crash never leaves half a model
behind. Every read error is a `ModelFormatError` naming the file.
"""
import json
import os
import time
from pathlib import Path
from typing import Dict, Optional, Tuple

import numpy as np

from traffic_gp.errors import ModelFormatError
from traffic_gp.observations import FIELDS, Observations

__all__ = ["FORMAT", "FORMAT_VERSION", "PARAM_PREFIX", "DATA_PREFIX", "SPATIAL_PREFIX",
           "PROFILE_PREFIX", "SERVING_PREFIX", "write_model_file", "read_header",
           "read_parameters", "read_spatial", "read_profile", "read_serving"]

FORMAT = "traffic_gp.TrafficGP"
FORMAT_VERSION = 1
PARAM_PREFIX = "param:"
DATA_PREFIX = "data:"
SPATIAL_PREFIX = "spatial:"
PROFILE_PREFIX = "profile:"
SERVING_PREFIX = "serving:"


def write_model_file(path, header: dict, parameters: Dict[str, np.ndarray],
                     data: Optional[Observations] = None,
                     spatial: Optional[Dict[str, np.ndarray]] = None,
                     profile: Optional[Dict[str, np.ndarray]] = None,
                     served: Optional[Dict[str, np.ndarray]] = None) -> Path:
    """Write `header` (JSON-able; `format`, `format_version` and `saved_at` are added), the named
    parameter arrays, the spatial-input, rate-profile and serving arrays (if any) and optionally
    the training rows to `path` (.npz); returns the path."""
    path = Path(path)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, **header}
    header.update(format=FORMAT, format_version=FORMAT_VERSION, saved_at=time.time())
    arrays = {PARAM_PREFIX + key: value for key, value in parameters.items()}
    arrays.update({SPATIAL_PREFIX + key: value for key, value in (spatial or {}).items()})
    arrays.update({PROFILE_PREFIX + key: value for key, value in (profile or {}).items()})
    arrays.update({SERVING_PREFIX + key: value for key, value in (served or {}).items()})
    if data is not None:
        arrays.update({DATA_PREFIX + name: getattr(data, name) for name in FIELDS})
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".partial.npz")
    np.savez_compressed(temporary, header=np.array(json.dumps(header)), **arrays)
    os.replace(temporary, path)
    return path


def read_header(path) -> dict:
    """The JSON header of a saved model (checks the format and version; no TensorFlow needed)."""
    with _open(path) as archive:
        return _header(archive, path)


def read_parameters(path, *, with_data: bool = False
                    ) -> Tuple[dict, Dict[str, np.ndarray], Optional[Observations]]:
    """(header, GP parameters in unconstrained form by path, training rows) of a saved model, read
    with NumPy only; the rows are None unless `with_data` and the file holds them."""
    with _open(path) as archive:
        header = _header(archive, path)
        values = {key[len(PARAM_PREFIX):]: archive[key] for key in archive.files
                  if key.startswith(PARAM_PREFIX)}
        data = None
        if with_data and all(DATA_PREFIX + name in archive.files for name in FIELDS):
            data = Observations(*(archive[DATA_PREFIX + name] for name in FIELDS))
    return header, values, data


def _prefixed(path, prefix: str) -> Dict[str, np.ndarray]:
    with _open(path) as archive:
        _header(archive, path)
        return {key[len(prefix):]: archive[key] for key in archive.files
                if key.startswith(prefix)}


def read_spatial(path) -> Dict[str, np.ndarray]:
    """The spatial-input arrays of a saved model by name (empty: the model works on x, y)."""
    return _prefixed(path, SPATIAL_PREFIX)


def read_profile(path) -> Dict[str, np.ndarray]:
    """The rate-profile arrays of a saved model by name (empty: the model has no offset)."""
    return _prefixed(path, PROFILE_PREFIX)


def read_serving(path) -> Dict[str, np.ndarray]:
    """The serving arrays of a saved model by name (empty: the model serves its GP alone)."""
    return _prefixed(path, SERVING_PREFIX)


def _open(path):
    try:
        return np.load(Path(path), allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        raise ModelFormatError(f"cannot read model file {path}: {err}") from err


def _header(archive, path) -> dict:
    try:
        header = json.loads(str(archive["header"]))
    except (KeyError, ValueError) as err:
        raise ModelFormatError(f"{path} is not a traffic_gp model file (no header)") from err
    if header.get("format") != FORMAT:
        raise ModelFormatError(f"{path} holds {header.get('format')!r}, not a {FORMAT} model")
    if header.get("format_version") != FORMAT_VERSION:
        raise ModelFormatError(f"{path} has model format version {header.get('format_version')}; "
                               f"this traffic_gp reads version {FORMAT_VERSION}")
    return header
