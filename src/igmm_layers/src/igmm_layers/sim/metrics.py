"""Scores of estimated object positions against the true ones (pure NumPy/SciPy)."""
from typing import Dict

import numpy as np

__all__ = ["ospa", "match_scores"]


def _distances(estimates, truth) -> np.ndarray:
    est = np.asarray(estimates, dtype=float).reshape(len(estimates), -1)
    true = np.asarray(truth, dtype=float).reshape(len(truth), -1)
    return np.linalg.norm(est[:, None, :] - true[None, :, :], axis=2)


def ospa(estimates, truth, *, cutoff: float = 1.0, order: float = 1.0) -> float:
    """Optimal sub-pattern assignment distance (Schuhmacher et al. 2008), in metres.

    Per-object localisation error under the best assignment, each distance capped at `cutoff`,
    and every unmatched object (missed or spurious) counted as `cutoff`.
    """
    from scipy.optimize import linear_sum_assignment

    m, n = len(estimates), len(truth)
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(cutoff)
    capped = np.minimum(_distances(estimates, truth), cutoff) ** order
    rows, cols = linear_sum_assignment(capped)
    total = capped[rows, cols].sum() + cutoff ** order * abs(m - n)
    return float((total / max(m, n)) ** (1.0 / order))


def match_scores(estimates, truth, *, radius: float = 0.5) -> Dict[str, float]:
    """One-to-one matching within `radius`: precision, recall, matches and mean matched error."""
    from scipy.optimize import linear_sum_assignment

    m, n = len(estimates), len(truth)
    if m == 0 or n == 0:
        return {"precision": 1.0 if m == 0 else 0.0, "recall": 1.0 if n == 0 else 0.0,
                "matched": 0, "mean_error": float("nan")}
    dist = _distances(estimates, truth)
    cost = np.where(dist <= radius, dist, 1e6)
    rows, cols = linear_sum_assignment(cost)
    ok = dist[rows, cols] <= radius
    matched = int(ok.sum())
    return {"precision": matched / m, "recall": matched / n, "matched": matched,
            "mean_error": float(dist[rows, cols][ok].mean()) if matched else float("nan")}
