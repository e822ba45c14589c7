"""Settings chosen on the user's own data: candidate GPs screened on the time-ordered hold-out.

A setting left at "auto" is chosen by `choose` from a small set of candidates:
  - `likelihood`: "poisson" or "negbin" (the count noise the GP trains with);
  - `profile` (the per-place rate offset): "none", "daily", and "weekly" once the fitting
    rows span WEEKLY_DAYS days (each weekday twice);
  - `spatial_inputs`: "geodesic" (walking distances; only with the map) or "xy";
  - `weekly` (the kernel's periods): False (24 h, with 1 h when `hourly`) or, once the fitting
    rows span WEEKLY_DAYS days, True (24 h and 168 h).
`hourly` ("auto") is not searched: the 1-hour cycle (the rush before the hour) is used when the
rows' times fall at different minutes of the hour, and left out for counts taken once an hour
(it cannot be seen in them).
Search (coordinate-wise, so about 4-6 candidates instead of the 24 combinations): the profiles
with the first likelihood, spatial input and the daily kernel; from the best of those the other
likelihood; from the best then the other spatial input; from the best then the weekly kernel.
Each candidate is a short fit (`screen_inducing` inducing points, at most `screen_steps` steps,
at most `screen_rows` fitting rows, a sample stratified by place and hour of the day:
`stratified_sample`) with early stopping on the held-out rows, scored by the held-out log
predictive density with its best interval width (`calibration.best_log_density`: candidates
compete on their forecasts, not on their noise models), among the candidates whose held-out RMSE of the
expected counts is within RMSE_SLACK of the least (the crowd map serves expected counts: a
likelihood that fits the quiet hours' spread better while missing the busy hours' means is
not chosen). The winner is then fitted once at full size.
Without a hold-out the defaults are: negative binomial (its trained dispersion is then the
only honest interval width), geodesic inputs with the map, no profile, the daily kernel.
"""
import logging
import time
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

import traffic_gp.predictive as predictive
from traffic_gp.calibration import best_log_density
from traffic_gp.observations import Observations

log = logging.getLogger(__name__)

AUTO = "auto"
WEEKLY_DAYS = 14
SCORE_ROWS = 5000        # held-out rows that score a candidate (a fixed random sample)
RMSE_SLACK = 0.02        # candidates this much above the least held-out RMSE are not chosen


def hourly_cycle_visible(t) -> bool:
    """Whether the rows' times fall at different minutes of the hour (10-minute slots)."""
    slots = np.unique(np.floor(np.mod(np.asarray(t, float), 1.0) * 6.0 + 1e-9))
    return slots.size > 1


def shortest_period(t) -> float:
    """The shortest period a harmonic forecaster may use: 2 h for counts taken once an hour
    (shorter periods alias), else 10 minutes."""
    return 1.0 / 6.0 if hourly_cycle_visible(t) else 2.0


def stratified_sample(rows: Observations, n: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of `n` of the rows (all when fewer), drawn per stratum of place (0.5 m)
    and hour of the day in proportion to its rows, so that every busy place and hour keeps its
    share (rounding up per stratum, then the surplus dropped at random)."""
    if len(rows) <= n:
        return np.arange(len(rows))
    place = np.floor(rows.x / 0.5) * 1e6 + np.floor(rows.y / 0.5)
    _, stratum = np.unique(np.column_stack([place, np.floor(np.mod(rows.t, 24.0))]), axis=0,
                           return_inverse=True)
    stratum = np.ravel(stratum)
    order = rng.permutation(len(rows))
    order = order[np.argsort(stratum[order], kind="stable")]        # shuffled within strata
    sizes = np.bincount(stratum)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    rank = np.arange(len(rows)) - starts[stratum[order]]
    quota = np.ceil(sizes * (n / len(rows))).astype(np.int64)
    keep = order[rank < quota[stratum[order]]]
    if keep.size > n:
        keep = rng.choice(keep, n, replace=False)
    return np.sort(keep)


def options(params: dict, *, has_map: bool, fit_days: int) -> Dict[str, list]:
    """Candidate values of each searched setting (one value where it is fixed)."""
    long_enough = fit_days >= WEEKLY_DAYS
    spaces = {"likelihood": ["poisson", "negbin"],
              "profile": ["none", "daily"] + (["weekly"] if long_enough else []),
              "spatial_inputs": (["geodesic", "xy"] if has_map else ["xy"]),
              "weekly": [False, True] if long_enough else [False]}
    out = {}
    for name, values in spaces.items():
        given = params[name]
        if given == AUTO:
            out[name] = values
        elif name == "spatial_inputs" and not has_map:
            out[name] = ["xy"]
        else:
            out[name] = [given]
    return out


def default_settings(params: dict, *, has_map: bool, hourly: bool) -> dict:
    """The settings without a hold-out (see the module)."""
    fixed = {"likelihood": "negbin", "profile": "none", "weekly": False,
             "spatial_inputs": "geodesic" if has_map else "xy"}
    settings = {name: (fixed[name] if params[name] == AUTO else params[name]) for name in fixed}
    if settings["spatial_inputs"] == "geodesic" and not has_map:
        settings["spatial_inputs"] = "xy"
    settings["hourly"] = hourly if params["hourly"] == AUTO else bool(params["hourly"])
    return settings


def _key(settings: dict) -> str:
    return (f"{settings['likelihood']}, profile {settings['profile']}, "
            f"{settings['spatial_inputs']}, {'weekly' if settings['weekly'] else 'daily'} kernel")


def choose(fit_candidate: Callable[[dict, Observations, Observations], object], params: dict,
           fit: Observations, held: Observations, *, has_map: bool, fit_days: int,
           hourly: bool, screen_rows: int, seed: int = 0) -> Tuple[dict, dict]:
    """(chosen settings, report) by the coordinate-wise search of the module docstring;
    `fit_candidate(settings, fit_rows, held_rows)` returns a fitted short GP."""
    space = options(params, has_map=has_map, fit_days=fit_days)
    rng = np.random.default_rng(seed)
    fit_rows = fit if len(fit) <= screen_rows else fit.subset(
        stratified_sample(fit, screen_rows, rng))
    held_rows = held if len(held) <= SCORE_ROWS else held.subset(
        np.sort(rng.choice(len(held), SCORE_ROWS, replace=False)))
    hourly = hourly if params["hourly"] == AUTO else bool(params["hourly"])
    searched = [name for name, values in space.items() if len(values) > 1]
    if not searched:
        settings = {name: values[0] for name, values in space.items()}
        return dict(settings, hourly=hourly), no_holdout_report(settings, "every setting given")
    scores: Dict[str, dict] = {}

    def score(settings: dict) -> float:
        key = _key(settings)
        if key not in scores:
            began = time.perf_counter()
            model = fit_candidate(dict(settings, hourly=hourly), fit_rows, held_rows)
            mean, var = model.predict_latent(held_rows.x, held_rows.y, held_rows.t)
            expected = held_rows.exposure * predictive.expected_value(mean, var)
            scores[key] = {
                "log_density": best_log_density(held_rows.count, mean, var, held_rows.exposure),
                "rmse": float(np.sqrt(np.mean((expected - held_rows.count) ** 2))),
                "steps": int(model.n_steps_), "seconds": round(time.perf_counter() - began, 1)}
            log.info("candidate %s: held-out log density %.4f, RMSE %.4g", key,
                     scores[key]["log_density"], scores[key]["rmse"])
        return scores[key]["log_density"]

    def best_of(candidates: List[dict]) -> dict:
        """Of the candidates whose held-out RMSE is within RMSE_SLACK of the least one, the one
        with the best held-out log density."""
        for candidate in candidates:
            score(candidate)
        least = min(scores[_key(c)]["rmse"] for c in candidates)
        close = [c for c in candidates if scores[_key(c)]["rmse"] <= (1 + RMSE_SLACK) * least]
        return max(close, key=score)

    first = {"spatial_inputs": space["spatial_inputs"][0], "weekly": space["weekly"][0],
             "likelihood": space["likelihood"][0]}
    best = best_of([dict(first, profile=pr) for pr in space["profile"]])
    for name in ("likelihood", "spatial_inputs", "weekly"):
        for value in space[name][1:]:
            best = best_of([best, dict(best, **{name: value})])
    mine = scores[_key(best)]
    others = sorted((item for item in scores.items() if item[0] != _key(best)),
                    key=lambda item: -item[1]["log_density"])
    reason = (f"chose {_key(best)} by held-out log density per count {mine['log_density']:.4f}"
              f" (RMSE {mine['rmse']:.4g})"
              + (f"; next {others[0][0]}: {others[0][1]['log_density']:.4f} (RMSE "
                 f"{others[0][1]['rmse']:.4g})" if others else "")
              + f"; searched {', '.join(searched)}")
    report = {"candidates": scores, "chosen": _key(best), "reason": reason,
              "screening": {"fit_rows": len(fit_rows), "held_out_rows": len(held_rows)}}
    return dict(best, hourly=hourly), report


def no_holdout_report(settings: dict, why: Optional[str] = None) -> dict:
    return {"candidates": {}, "chosen": _key(settings),
            "reason": f"{_key(settings)}: "
                      f"{why or 'defaults, no time-ordered hold-out (too few rows or days)'}"}
