"""A forecast's level, updated as new counts arrive (rolling origin), with its uncertainty.

A crowd model learnt on one period forecasts the shape of the week well but not the level of a
later one: a holiday season, a closure or a lockdown scales every count of a place. Online, the
counts of the week just past are known when the next week is forecast. `level_factors` gives
each forecast row the factor counts / forecast of its place over the 7 days before the row's
week (the last-week level correction); `level_latent` puts that factor and its uncertainty into
the Gaussian over the log rate (f -> f + log factor + e, e ~ N(-s/2, s): the expected count is
the corrected forecast, the log level of next week is uncertain by variance s), so count
intervals include the level's uncertainty; `rolling_level_variance` lets s grow online after
weeks whose level moved more (a shock); `calibrate` chooses s and the negative binomial's
dispersion r by the log predictive density of held-out weeks (validation, never the test).
NumPy only.
"""
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

import traffic_gp.predictive as predictive

HOURS_PER_WEEK = 168
CLIP = (0.02, 5.0)
LEVEL_VARIANCES = (0.0, 0.005, 0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.25, 0.4, 0.7, 1.0)
DISPERSIONS = tuple(float(r) for r in np.exp(np.linspace(np.log(0.5), np.log(1000.0), 16)))


def level_factors(history: Dict[str, np.ndarray], history_forecast: np.ndarray,
                  rows: Dict[str, np.ndarray], origin_hour: int,
                  clip: Tuple[float, float] = CLIP) -> np.ndarray:
    """Per forecast row: (counts / forecast) of its key over the week before the row's week,
    clipped to `clip`; 1 where that week holds no counts of the key.

    `history` and `rows` are dicts of arrays with `key` (a place id), `abs_hour` (hours since
    an epoch) and, in `history`, `count`; weeks are counted from `origin_hour` (week 0 starts
    there); `history_forecast` is the forecast at the history rows."""
    week = (np.asarray(rows["abs_hour"]) - origin_hour) // HOURS_PER_WEEK
    factors = np.ones(week.size)
    h_hour, h_key = np.asarray(history["abs_hour"]), np.asarray(history["key"])
    h_count, h_pred = np.asarray(history["count"], float), np.asarray(history_forecast, float)
    for w in np.unique(week):
        lo = origin_hour + HOURS_PER_WEEK * (w - 1)
        inside = (h_hour >= lo) & (h_hour < lo + HOURS_PER_WEEK)
        in_week = week == w
        for key in np.unique(rows["key"][in_week]):
            sel = inside & (h_key == key)
            predicted = h_pred[sel].sum()
            if sel.any() and predicted > 0:
                factors[in_week & (rows["key"] == key)] = np.clip(
                    h_count[sel].sum() / predicted, *clip)
    return factors


def rolling_level_variance(history: Dict[str, np.ndarray], history_forecast: np.ndarray,
                           rows: Dict[str, np.ndarray], origin_hour: int, floor: float,
                           window: int = 4, clip: Tuple[float, float] = CLIP) -> np.ndarray:
    """Per forecast row: the variance of its week's log level around last week's, as seen
    online: the mean square of the keys' changes of weekly log level (log counts / forecast,
    clipped) between consecutive weeks over the `window` weeks before the row's week, never
    below `floor` (the variance chosen on held-out weeks). After a shock (a lockdown) the
    intervals widen for the following weeks, as the changes just seen warrant."""
    h_week = (np.asarray(history["abs_hour"]) - origin_hour) // HOURS_PER_WEEK
    h_key = np.asarray(history["key"])
    h_count, h_pred = np.asarray(history["count"], float), np.asarray(history_forecast, float)
    table = {}
    for key in np.unique(h_key):
        of_key = h_key == key
        for w in np.unique(h_week[of_key]):
            sel = of_key & (h_week == w)
            predicted = h_pred[sel].sum()
            if predicted > 0:
                table[(int(key), int(w))] = float(np.log(np.clip(h_count[sel].sum() / predicted,
                                                                 *clip)))
    week = (np.asarray(rows["abs_hour"]) - origin_hour) // HOURS_PER_WEEK
    out = np.full(week.size, float(floor))
    for w in np.unique(week):
        changes = [value - table[(k, j - 1)] for (k, j), value in table.items()
                   if w - window <= j <= w - 1 and (k, j - 1) in table]
        if changes:
            out[week == w] = max(float(floor), float(np.mean(np.square(changes))))
    return out


def level_latent(mean, var, factor, level_var) -> Tuple[np.ndarray, np.ndarray]:
    """The Gaussian over the log rate with the level: mean + log factor - s/2, var + s (s =
    `level_var`, one value or one per row), so that E[exp(f)] is the forecast's times
    `factor`."""
    s = np.asarray(level_var, float)
    return (np.asarray(mean, float) + np.log(np.asarray(factor, float)) - s / 2.0,
            np.asarray(var, float) + s)


def calibrate(count, mean, var, factor, expo=1.0,
              level_variances: Sequence[float] = LEVEL_VARIANCES,
              dispersions: Sequence[float] = DISPERSIONS,
              fixed_dispersion: Optional[float] = None) -> Dict[str, object]:
    """The level variance s and the negative-binomial dispersion r (or `fixed_dispersion`)
    maximising the mean log predictive density of `count` under `level_latent`; returns
    {"level_var", "dispersion", "log_density"}. Use held-out (validation) weeks."""
    count = np.asarray(count, float)
    best = None
    for r in ([fixed_dispersion] if fixed_dispersion is not None else dispersions):
        for s in level_variances:
            m, v = level_latent(mean, var, factor, s)
            score = float(np.mean(predictive.log_density(count, m, v, expo, r)))
            if best is None or score > best["log_density"]:
                best = {"level_var": float(s), "dispersion": r, "log_density": score}
    return best
