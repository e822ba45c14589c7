"""Saving and loading trained crowd models: one `.npz` file, versioned, loaded without training.

The file holds a JSON header (`format`, `format_version`, the estimator's parameters, training
statistics, library versions, caller metadata such as the map it was trained on), every GP
parameter in its unconstrained form (so a loaded model predicts bit for bit what the saved one
did) and, optionally, the training rows (so `partial_fit` can continue after loading).
Files are written to a temporary name and renamed: a crash never leaves half a model behind.
"""
import json
import os
import time
from pathlib import Path
from typing import Optional

import numpy as np

from traffic_gp.errors import ModelFormatError, NotFittedError
from traffic_gp.observations import FIELDS, Observations

FORMAT = "traffic_gp.TrafficGP"
FORMAT_VERSION = 1
PARAM_PREFIX = "param:"
DATA_PREFIX = "data:"


def save_model(estimator, path, *, include_data: bool = True, meta: Optional[dict] = None) -> Path:
    """Write a fitted `TrafficGP` to `path` (.npz); returns the path."""
    from traffic_gp import gp_parts

    if not hasattr(estimator, "model_"):
        raise NotFittedError("cannot save a TrafficGP that is not fitted")
    path = Path(path)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "params": estimator.get_params(),
              "n_steps": estimator.n_steps_, "n_rows": len(estimator.data_),
              "elbo": estimator.elbo_[-1] if estimator.elbo_ else None,
              "train_seconds": estimator.train_seconds_, "saved_at": time.time(),
              "libraries": gp_parts._L.versions, "meta": meta or {}}
    arrays = {PARAM_PREFIX + key: value
              for key, value in gp_parts.parameter_values(estimator.model_).items()}
    if include_data:
        arrays.update({DATA_PREFIX + name: getattr(estimator.data_, name) for name in FIELDS})
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".partial.npz")
    np.savez_compressed(temporary, header=np.array(json.dumps(header)), **arrays)
    os.replace(temporary, path)
    return path


def read_header(path) -> dict:
    """The JSON header of a saved model (checks the format and version; no TensorFlow needed)."""
    with _open(path) as archive:
        return _header(archive, path)


def read_parameters(path, *, with_data: bool = False):
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


def load_model(path):
    """A `TrafficGP` with the saved parameters; nothing is trained."""
    from traffic_gp import gp_parts
    from traffic_gp.model import TrafficGP

    header, values, data = read_parameters(path, with_data=True)
    try:
        estimator = TrafficGP(**header["params"])
        inducing = values[".inducing_variable.Z"]
    except (TypeError, KeyError) as err:
        raise ModelFormatError(f"{path}: the saved model lacks {err}") from err
    estimator._rng = np.random.default_rng(estimator.random_state)
    estimator.model_ = gp_parts.build_model(
        inducing, spatial_lengthscale=estimator.spatial_lengthscale, hourly=estimator.hourly,
        weekly=estimator.weekly, log_mean=0.0, num_data=header["n_rows"],
        train_inducing=estimator.train_inducing)
    gp_parts.assign_parameter_values(estimator.model_, values)
    estimator.data_ = data if data is not None else Observations.empty()
    estimator.n_steps_, estimator.train_seconds_ = header["n_steps"], header["train_seconds"]
    estimator.compile_seconds_ = 0.0
    estimator.elbo_ = [header["elbo"]] if header["elbo"] is not None else []
    estimator.meta_ = header["meta"]
    estimator._trainer = None
    return estimator


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
