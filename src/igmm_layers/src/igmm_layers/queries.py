"""Questions to the object layers, answered from cluster tables (pure NumPy/SciPy).

- `most_likely` / `closest`: simple lookup of one cluster;
- `pair_likelihood`: how likely class A is found near class B, by one of two methods:
  "distance_weighted" (default; the original's and the report's definition): the mean over
  cluster pairs (a_i, b_j) in the same region whose means are at most `max_distance` apart of
  p(mu_a | b) = N(mu_a; mu_b, C_b), weighted by exp(-d / 1 m). Asymmetric, ignores A's spread
  and the clusters' weights.
  "overlap" (a named option): sum over the same pairs of w_a w_b N(mu_a; mu_b, C_a + C_b), the
  integral of p_A(x) p_B(x) over the map (restricted to pairs in range): the density of finding an A and
  a B at the same place. Symmetric, uses both spreads and the mixture weights.
  Both are densities (1/m^2 in 2-D), comparable across classes B for a fixed A.
- `alternate_classes`: the other classes ranked by pair likelihood with a class;
- `count_observed`: clusters (objects) with observations in a time window near a point.
"""
import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from igmm_layers.errors import InvalidInputError, NotFittedError
from igmm_layers.layers import ClusterTable

__all__ = ["PAIR_METHODS", "DEFAULT_PAIR_METHOD", "DEFAULT_MAX_DISTANCE", "most_likely", "closest",
           "pair_likelihood", "alternate_classes", "count_observed"]

PAIR_METHODS = ("distance_weighted", "overlap")
DEFAULT_PAIR_METHOD = "distance_weighted"
DEFAULT_MAX_DISTANCE = 5.0
_DISTANCE_SCALE = 1.0  # m, of the original's exp(-d) weighting


def _require(table: ClusterTable, what: str) -> None:
    if not len(table):
        raise NotFittedError(f"no clusters of {what} yet")


def _point(point: Sequence[float], dim: int) -> np.ndarray:
    p = np.asarray(point, dtype=float)[:dim]
    if len(p) < dim or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"point must have {dim} finite coordinates, got {list(point)}")
    return p


def most_likely(table: ClusterTable, what: str = "the class") -> int:
    """Index of the cluster with the most support (= the largest weight within one class)."""
    _require(table, what)
    return int(np.argmax(table.support))


def closest(table: ClusterTable, point: Sequence[float], what: str = "the class") -> Tuple[int, float]:
    """Index of the cluster whose mean is nearest to `point`, and that distance (m)."""
    _require(table, what)
    dist = np.linalg.norm(table.means - _point(point, table.means.shape[1]), axis=1)
    best = int(np.argmin(dist))
    return best, float(dist[best])


def _check_pair_args(max_distance: float, method: str) -> Tuple[float, str]:
    method = method or DEFAULT_PAIR_METHOD
    if method not in PAIR_METHODS:
        raise InvalidInputError(f"unknown method {method!r}; methods: {', '.join(PAIR_METHODS)}")
    if max_distance == 0:
        max_distance = DEFAULT_MAX_DISTANCE
    if not (max_distance > 0 and math.isfinite(max_distance)):
        raise InvalidInputError(f"max_distance must be positive (0: {DEFAULT_MAX_DISTANCE} m), "
                                f"got {max_distance}")
    return float(max_distance), method


def _gauss(diff: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """N(diff; 0, cov) for rows of diff (n, D) and covs (n, D, D)."""
    dim = diff.shape[1]
    if dim == 2:  # closed form: no per-matrix LAPACK calls
        a, b, d = covs[:, 0, 0], covs[:, 0, 1], covs[:, 1, 1]
        det = a * d - b * b
        maha = (d * diff[:, 0] ** 2 - 2 * b * diff[:, 0] * diff[:, 1] + a * diff[:, 1] ** 2) / det
        return np.exp(-0.5 * maha) / (2 * math.pi * np.sqrt(det))
    prec = np.linalg.inv(covs)
    maha = np.einsum("nd,nde,ne->n", diff, prec, diff)
    log_det = np.linalg.slogdet(covs)[1]
    return np.exp(-0.5 * (maha + log_det + dim * math.log(2 * math.pi)))


def _pairs_in_range(a: ClusterTable, b: ClusterTable, max_distance: float):
    """Index arrays (i in a, j in b) of pairs in the same region within max_distance, and d."""
    from scipy.spatial import cKDTree

    rows: List[np.ndarray] = []
    cols: List[np.ndarray] = []
    for region in sorted(set(a.region_ids) & set(b.region_ids)):
        ia = np.flatnonzero(np.array(a.region_ids) == region)
        ib = np.flatnonzero(np.array(b.region_ids) == region)
        pairs = cKDTree(a.means[ia]).sparse_distance_matrix(
            cKDTree(b.means[ib]), max_distance, output_type="ndarray")
        rows.append(ia[pairs["i"]])
        cols.append(ib[pairs["j"]])
    i = np.concatenate(rows) if rows else np.zeros(0, dtype=int)
    j = np.concatenate(cols) if cols else np.zeros(0, dtype=int)
    return i, j, np.linalg.norm(a.means[i] - b.means[j], axis=1)


def pair_likelihood(a: ClusterTable, b: ClusterTable, *, max_distance: float = 0.0,
                    method: str = "") -> Tuple[float, str, int]:
    """(likelihood, method used, number of pairs) of finding A near B (see the module docstring)."""
    max_distance, method = _check_pair_args(max_distance, method)
    i, j, dist = _pairs_in_range(a, b, max_distance)
    if len(i) == 0:
        return 0.0, method, 0
    diff = a.means[i] - b.means[j]
    if method == "distance_weighted":
        weights = np.exp(-dist / _DISTANCE_SCALE)
        value = float(np.sum(weights * _gauss(diff, b.covariances[j])) / np.sum(weights))
    else:
        value = float(np.sum(a.weights[i] * b.weights[j]
                             * _gauss(diff, a.covariances[i] + b.covariances[j])))
    return value, method, int(len(i))


def alternate_classes(table_of, class_name: str, candidates: Sequence[str], *,
                      max_distance: float = 0.0, method: str = "") -> Tuple[List[Tuple[str, float]], str]:
    """Candidates ranked by pair likelihood with `class_name` (zero likelihoods left out).

    `table_of(name)` gives the ClusterTable of a class.
    """
    max_distance, method = _check_pair_args(max_distance, method)
    target = table_of(class_name)
    _require(target, repr(class_name))
    scores = []
    for other in candidates:
        if other == class_name:
            continue
        value, _, _ = pair_likelihood(table_of(other), target, max_distance=max_distance, method=method)
        if value > 0:
            scores.append((other, value))
    scores.sort(key=lambda item: (-item[1], item[0]))
    return scores, method


def count_observed(table: ClusterTable, *, start: Optional[float] = None, end: Optional[float] = None,
                   center: Optional[Sequence[float]] = None, radius: float = 0.0
                   ) -> Dict[str, Tuple[int, int]]:
    """Per class: (clusters with an observation in [start, end] within `radius` of `center`,
    observations of theirs in the window). None/0 mean no limit."""
    if start is not None and end is not None and start > end:
        raise InvalidInputError(f"time window starts after it ends ({start} > {end})")
    if radius < 0 or not math.isfinite(radius):
        raise InvalidInputError(f"radius must be >= 0 (0: no limit), got {radius}")
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    near = np.ones(len(table), dtype=bool)
    if radius > 0 and len(table):
        if center is None:
            raise InvalidInputError("a radius needs a center point")
        near = np.linalg.norm(table.means - _point(center, table.means.shape[1]), axis=1) <= radius
    counts: Dict[str, Tuple[int, int]] = {}
    for k in np.flatnonzero(near & (table.last_seen >= lo) & (table.first_seen <= hi)):
        times = np.asarray(table.times[k])
        seen = int(np.count_nonzero((times >= lo) & (times <= hi)))
        objects, observations = counts.get(table.class_names[k], (0, 0))
        counts[table.class_names[k]] = (objects + (seen > 0), observations + seen)
    return counts
