"""Input checks, batch ordering and state restoring for the IncrementalGMM (pure NumPy)."""
from typing import List, Optional, Sequence, Tuple

import numpy as np

from igmm_layers.errors import InvalidInputError

__all__ = ["validate_samples", "rank_one_terms", "canonical_order", "restore_components"]


def _bad_rows(mask: np.ndarray) -> str:
    rows = np.flatnonzero(mask)
    return f"rows {rows[:5].tolist()}{' ...' if len(rows) > 5 else ''}"


def validate_samples(X, sample_weight, measurement_cov, times, dim: Optional[int], t0: float,
                     same_time: bool = False
                     ) -> Tuple[np.ndarray, np.ndarray, Optional[np.ndarray], np.ndarray]:
    """X (n, D), weights (n,), covariances (n, D, D) or None, times (n,), all float and checked."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[1] == 0:
        raise InvalidInputError(f"X must be a 2-D array (n_samples, n_features), got shape {X.shape}")
    n = len(X)
    if dim is None and n == 0:
        raise InvalidInputError("X is empty: the first data must have at least one row")
    if dim is not None and X.shape[1] != dim:
        raise InvalidInputError(f"X has {X.shape[1]} features, the model has {dim}")
    finite = np.all(np.isfinite(X), axis=1)
    if not finite.all():
        raise InvalidInputError(f"X has NaN or infinite values in {_bad_rows(~finite)}")
    weights = np.ones(n) if sample_weight is None else np.asarray(sample_weight, dtype=float)
    if weights.shape != (n,):
        raise InvalidInputError(f"sample_weight must have shape ({n},), got {weights.shape}")
    bad = ~(np.isfinite(weights) & (weights > 0))
    if bad.any():
        raise InvalidInputError(f"sample_weight must be positive and finite; bad {_bad_rows(bad)}: "
                                f"{weights[bad][:5].tolist()}")
    covs = None if measurement_cov is None else _check_covariances(measurement_cov, n, X.shape[1])
    if times is None:
        times = np.full(n, float(t0)) if same_time else t0 + np.arange(n, dtype=float)
    times = np.asarray(times, dtype=float)
    if times.shape != (n,) or not np.all(np.isfinite(times)):
        raise InvalidInputError(f"times must be {n} finite numbers, got shape {times.shape}")
    return X, weights, covs, times


def _check_covariances(measurement_cov, n: int, dim: int) -> np.ndarray:
    covs = np.asarray(measurement_cov, dtype=float)
    if covs.shape == (n, dim):
        if np.any(covs < 0) or not np.all(np.isfinite(covs)):
            raise InvalidInputError("measurement variances must be finite and non-negative")
        covs = np.einsum("nd,de->nde", covs, np.eye(dim))
    if covs.shape != (n, dim, dim) or not np.all(np.isfinite(covs)):
        raise InvalidInputError(f"measurement_cov must be finite with shape ({n}, {dim}, {dim}) or "
                                f"({n}, {dim}), got {covs.shape}")
    scale = np.abs(covs).max(axis=(1, 2)) + 1e-300
    asym = np.abs(covs - np.swapaxes(covs, 1, 2)).max(axis=(1, 2)) > 1e-9 * scale
    negative = np.linalg.eigvalsh(0.5 * (covs + np.swapaxes(covs, 1, 2))).min(axis=1) < -1e-9 * scale
    if (asym | negative).any():
        raise InvalidInputError("measurement_cov must be symmetric positive semi-definite; "
                                f"bad {_bad_rows(asym | negative)}")
    return covs


def rank_one_terms(covs: np.ndarray) -> List[List[Tuple[float, np.ndarray]]]:
    """Each covariance as a sum of lam * u u^T terms (its non-zero eigen-directions)."""
    values, vectors = np.linalg.eigh(0.5 * (covs + np.swapaxes(covs, 1, 2)))
    terms = []
    for vals, vecs in zip(values, vectors):
        floor = 1e-12 * max(float(vals.max()), 0.0)
        terms.append([(float(lam), np.ascontiguousarray(vecs[:, k])) for k, lam in enumerate(vals)
                      if lam > floor and lam > 0])
    return terms


def canonical_order(X: np.ndarray, weights: np.ndarray, times: np.ndarray,
                    covs: Optional[np.ndarray]) -> np.ndarray:
    """A pseudo-random order of the rows that depends only on their values.

    Each row (coordinates, weight, time, covariance) is hashed (64-bit multiply-xorshift of its
    bytes) and the rows are sorted by hash, ties by value; so any permutation of the same rows
    gives the same sequence of updates (bit-identical results), and the sequence is as well
    mixed as a random order (no sweep across space or time, which hurts incremental learners).
    """
    columns = [X, weights[:, None], times[:, None]]
    if covs is not None:
        columns.append(covs.reshape(len(X), -1))
    data = np.ascontiguousarray(np.concatenate(columns, axis=1)) + 0.0  # -0.0 -> 0.0
    words = data.view(np.uint64)
    mixed = np.full(len(X), 0x243F6A8885A308D3, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for k in range(words.shape[1]):
            mixed = (mixed ^ words[:, k]) * np.uint64(0x9E3779B97F4A7C15)
            mixed ^= mixed >> np.uint64(29)
    keys = [data[:, k] for k in reversed(range(data.shape[1]))] + [mixed]
    return np.lexsort(keys)


def _component_arrays(components: Sequence[dict], dim: int):
    try:
        means = np.array([c["mean"] for c in components], dtype=float).reshape(-1, dim)
        covs = np.array([c["covariance"] for c in components], dtype=float).reshape(-1, dim, dim)
        support = np.array([c["support"] for c in components], dtype=float)
        ages = np.array([c.get("age", 1) for c in components], dtype=np.int64)
        times = [sorted(float(t) for t in c.get("times", ())) for c in components]
        first = np.array([c.get("first_seen", t[0] if t else 0.0) for c, t in zip(components, times)],
                         dtype=float)
        last = np.array([c.get("last_seen", t[-1] if t else 0.0) for c, t in zip(components, times)],
                        dtype=float)
    except (KeyError, TypeError, ValueError) as err:
        raise InvalidInputError(f"malformed component in IncrementalGMM state: {err}") from err
    if not (np.all(np.isfinite(means)) and np.all(support > 0) and np.all(ages >= 1)):
        raise InvalidInputError("component means must be finite, supports positive, ages >= 1")
    try:
        np.linalg.cholesky(covs)
    except np.linalg.LinAlgError as err:
        raise InvalidInputError("a component covariance is not positive definite") from err
    return means, covs, support, ages, times, first, last


def restore_components(model, state: dict) -> None:
    """Fill a fresh model with the components of a `to_dict` state."""
    try:
        dim = int(state["n_features_in"])
        components = list(state["components"])
    except (KeyError, TypeError, ValueError) as err:
        raise InvalidInputError(f"not an IncrementalGMM state: {err}") from err
    means, covs, support, ages, times, first, last = _component_arrays(components, dim)
    model._reset(dim)
    n_updates = max(int(state.get("n_updates", 0)), int(ages.max(initial=1)) - 1)
    model.n_updates_ = n_updates
    model.n_samples_seen_ = int(state.get("n_samples_seen", 0))
    model.means_, model.covariances_, model.support_ = means, covs, support
    model.born_ = n_updates - (ages - 1)
    model.ids_ = np.arange(len(support), dtype=np.int64)
    model._next_id = len(support)
    model.first_seen_, model.last_seen_ = first, last
    model.observation_times_ = [t[-model.max_times:] for t in times]
    model.precisions_ = np.zeros_like(covs)
    model.log_dets_ = np.zeros(len(support))
    model._log_score = np.zeros(len(support))
    model.refresh()
    model._rebuild_prune_queue()
