"""Interval width chosen on held-out counts: the count dispersion and an extra latent variance.

A forecast gives a Gaussian over the log rate (mean m, variance v; a point forecast has v = 0)
and a count distribution around it (Poisson, or negative binomial with dispersion r). How wide
its intervals should be is a question for data the forecast was not fitted on. `calibrate`
tries every dispersion of DISPERSIONS (None: Poisson) and every extra latent variance s of
LATENT_VARIANCES (the log rate becomes N(m - s/2, v + s): the expected count stays the same,
the forecast's level is uncertain by s) and measures two coverages of the central 90%
intervals on the held-out counts: the plain share inside them (what a user of the intervals
sees) and the share by the randomised PIT (`pit_share`: the measure a calibrated forecast meets
also for small counts, where even the true distribution holds more than 90% inside). It keeps
the widths whose coverages are nearest 90% (the larger of the two gaps to 90% within NEAR of
the least one: toward 90%, not merely above a floor; for counts of tens and more both measures
agree) and, of those, the one with the best mean log predictive density. COVERAGE_BAND is the
band a calibrated forecast's held-out coverage is expected in. `best_log_density` is the same
search without the coverage: the held-out log density a forecast reaches with its best
interval width, the score `selection` compares candidate models by (so the comparison is
between forecasts, not between their noise models). NumPy only; the count likelihood is
`predictive`'s.

Days differ: a held-out week with a holiday, an event or a sensor fault needs far wider
intervals than the days the model then forecasts, and pooled coverage would widen every
interval for them (intervals holding 96-99% on ordinary days). Given the counts' times,
`calibrate` measures both coverages per held-out day and uses the median day's (with at least
MIN_DAYS days of at least MIN_DAY_ROWS counts; else the pooled share): a width is chosen for
the typical day, and a few unusual days cannot set it.
"""
from dataclasses import asdict, dataclass
from typing import Optional, Tuple

import numpy as np

import traffic_gp.predictive as predictive

DISPERSIONS = (None,) + tuple(float(r) for r in np.exp(np.linspace(np.log(0.3), np.log(1000.0),
                                                                    14)))
LATENT_VARIANCES = (0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5)
LEVEL = 0.9
COVERAGE_BAND = (0.875, 0.925)     # where a calibrated forecast's held-out coverage lies
NEAR = 0.01             # widths this much further from 90% than the nearest compete on density
MAX_ROWS = 3000         # held-out rows used (a fixed random sample of them)
SCREEN_ROWS = 1000      # rows every width's coverage is first measured on
SCREEN_SLACK = 0.03     # widths this much further from 90% on them are measured on all rows
N_NODES = 10            # quadrature nodes over the log rate
MIN_DAYS = 3            # held-out days for the median day's coverage (fewer: pooled)
MIN_DAY_ROWS = 20       # counts a held-out day needs to count as one


@dataclass
class Calibration:
    """The chosen interval width and what it gave on the held-out counts."""

    dispersion: Optional[float]       # None: Poisson counts
    latent_variance: float
    coverage: float                   # held-out 90% coverage by the randomised PIT
    log_density: float                # mean held-out log predictive density per count
    coverage_inside: float = float("nan")   # share of held-out counts inside the intervals

    def to_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        """The chosen width and its held-out coverage, for status lines."""
        noise = "Poisson" if self.dispersion is None \
            else f"negative binomial r={self.dispersion:.3g}"
        return (f"90% intervals: {noise}, extra log-rate variance {self.latent_variance:g}, "
                f"held-out coverage {self.coverage_inside:.3f} (randomised PIT "
                f"{self.coverage:.3f})")

    @classmethod
    def from_dict(cls, values: dict) -> "Calibration":
        return cls(None if values.get("dispersion") is None else float(values["dispersion"]),
                   float(values["latent_variance"]), float(values["coverage"]),
                   float(values["log_density"]),
                   float(values.get("coverage_inside", float("nan"))))


def widen(mean, var, latent_variance: float) -> Tuple[np.ndarray, np.ndarray]:
    """The log-rate Gaussian with the extra variance s: N(mean - s/2, var + s)."""
    s = float(latent_variance)
    return np.asarray(mean, float) - s / 2.0, np.asarray(var, float) + s


def log_density(count, mean, var, expo, dispersion) -> float:
    """Mean log predictive density of the counts (the mixture over the log rate)."""
    return float(np.mean(predictive.log_density(count, mean, var, expo, dispersion,
                                                n_nodes=N_NODES)))


def _cdf_pair(count, mean, var, expo, dispersion):
    """(F(k - 1), F(k)) of the mixture at each count k."""
    count = np.asarray(count, float).ravel()
    rates, weights = predictive.node_rates(mean, var, expo, N_NODES)
    return (predictive.component_cdf(count - 1.0, rates, dispersion) @ weights,
            predictive.component_cdf(count, rates, dispersion) @ weights)


def _shares(lower, upper, level: float = LEVEL, days=None) -> Tuple[float, float]:
    """(inside share, PIT share) from F(k - 1) and F(k) of each count: k is inside the central
    `level` interval exactly when F(k) >= tail and F(k - 1) < 1 - tail; its randomised PIT is
    uniform on [F(k - 1), F(k)], and the PIT share is the expected share of counts whose PIT
    falls in the central band (`level` for a calibrated forecast whatever the counts' size,
    while the inside share of small counts is above `level` even for the true distribution).
    With `days` (a day index per count, see `day_index`): the median day's shares."""
    tail = (1.0 - level) / 2.0
    inside = (upper >= tail - 1e-9) & (lower < 1.0 - tail - 1e-9)
    overlap = np.clip(np.minimum(upper, 1.0 - tail) - np.maximum(lower, tail), 0.0, None)
    width = upper - lower
    within = ((lower >= tail) & (upper <= 1.0 - tail)).astype(float)
    pit = np.where(width > 1e-12, overlap / np.maximum(width, 1e-12), within)
    if days is None:
        return float(np.mean(inside)), float(np.mean(pit))
    n = np.bincount(days).astype(float)
    used = n > 0
    return tuple(float(np.median(np.bincount(days, share.astype(float))[used] / n[used]))
                 for share in (inside, pit))


def day_index(t, min_days: int = MIN_DAYS, min_rows: int = MIN_DAY_ROWS) -> Optional[np.ndarray]:
    """Per count at times `t` (hours): the index of its day among the days with at least
    `min_rows` counts (counts of smaller days join the nearest earlier such day, or the first),
    or None when fewer than `min_days` days have that many (the pooled share is used then)."""
    day = np.floor(np.asarray(t, float).ravel() / 24.0)
    days, index, n = np.unique(day, return_inverse=True, return_counts=True)
    kept = np.nonzero(n >= min_rows)[0]
    if kept.size < min_days:
        return None
    owner = np.searchsorted(kept, np.arange(days.size), side="right") - 1
    return np.maximum(owner, 0)[np.ravel(index)]


def inside_share(count, mean, var, expo, dispersion, level: float = LEVEL) -> float:
    """Share of counts inside the central `level` interval."""
    return _shares(*_cdf_pair(count, mean, var, expo, dispersion), level)[0]


def pit_share(count, mean, var, expo, dispersion, level: float = LEVEL) -> float:
    """Expected share of counts whose randomised PIT falls in the central `level` band."""
    return _shares(*_cdf_pair(count, mean, var, expo, dispersion), level)[1]


def _sample(n: int, max_rows: int, seed: int) -> np.ndarray:
    if n <= max_rows:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, max_rows, replace=False))


def _grid(count, mean, var, expo):
    """[(dispersion, latent variance, mean log density)] over the whole grid."""
    out = []
    for r in DISPERSIONS:
        for s in LATENT_VARIANCES:
            m, v = widen(mean, var, s)
            out.append((r, s, log_density(count, m, v, expo, r)))
    return out


def _rows(count, mean, var, expo, max_rows: int, seed: int, t=None):
    count = np.asarray(count, float).ravel()
    pick = _sample(count.size, max_rows, seed)
    arrays = [np.broadcast_to(np.asarray(a, float), count.shape)[pick] for a in (mean, var, expo)]
    days = None if t is None else day_index(np.broadcast_to(np.asarray(t, float),
                                                             count.shape)[pick])
    return (count[pick], *arrays), days


def best_log_density(count, mean, var, expo=1.0, *, max_rows: int = MAX_ROWS,
                     seed: int = 0) -> float:
    """The mean held-out log density of a forecast with its best interval width."""
    rows, _ = _rows(count, mean, var, expo, max_rows, seed)
    return max(score for _, _, score in _grid(*rows))


def calibrate(count, mean, var, expo=1.0, *, t=None, max_rows: int = MAX_ROWS,
              seed: int = 0) -> Calibration:
    """The interval width for held-out counts (see the module docstring); `t`: the counts'
    times in hours (then the median day's coverages are matched). The coverages of every width
    are first measured on SCREEN_ROWS of the rows, then those of the widths near the nearest
    on all of them."""
    (count, mean, var, expo), days = _rows(count, mean, var, expo, max_rows, seed, t)
    grid = _grid(count, mean, var, expo)
    few = _sample(count.size, SCREEN_ROWS, seed + 1)
    few_days = None if days is None else days[few]
    screened = [(_gap(count[few], mean[few], var[few], expo[few], r, s, few_days), r, s, score)
                for r, s, score in grid]
    least = min(g[0] for g in screened)
    tried = []
    for _, r, s, score in (g for g in screened if g[0] <= least + NEAR + SCREEN_SLACK):
        inside, pit = _shares(*_cdf_pair(count, *widen(mean, var, s), expo, r), days=days)
        tried.append((r, s, score, pit, inside, max(abs(pit - LEVEL), abs(inside - LEVEL))))
    least = min(g[5] for g in tried)
    r, s, score, pit, inside, _ = max((g for g in tried if g[5] <= least + NEAR),
                                      key=lambda g: g[2])
    return Calibration(r, s, pit, score, inside)


def _gap(count, mean, var, expo, dispersion, latent_variance, days=None) -> float:
    """The larger of the two coverages' distances to the level."""
    inside, pit = _shares(*_cdf_pair(count, *widen(mean, var, latent_variance), expo,
                                     dispersion), days=days)
    return max(abs(pit - LEVEL), abs(inside - LEVEL))
