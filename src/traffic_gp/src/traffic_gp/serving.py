"""What a fitted crowd model serves: the GP, or a simple forecaster where that forecast the
held-out days better, with interval widths calibrated on those days.

`build` fits the two baselines (`baselines.FreMEn`, `baselines.BinnedMean`) on the same rows
the GP was fitted on, each with its setting (period, order, bin width) chosen by the squared
error of its forecast of the held-out (most recent) days, forms the blend of the GP and the
better baseline (expected counts w x GP + (1 - w) x baseline, w of BLEND_WEIGHTS chosen on the
same days: a combination of two forecasts whose errors differ beats either where both are
good), and compares the four forecasts of those days:
  - the GP is served only when it earns its cost: when neither the GP nor the blend has a
    held-out RMSE of at most GP_MARGIN (0.9) times the best baseline's (`gp_ratio`: against
    the rates, the counts' Poisson noise, their mean, taken out of each squared error), the
    best baseline is served everywhere (other baselines at places where clearly better) and
    the status says so ("GP 1.00x the best baseline on the held-out days: serving the
    baselines");
  - else the GP is served everywhere (`default`) unless another forecast was clearly better over the
    held-out days: its squared errors of the counts, summed per place and day, are lower than
    the GP's by more than SWITCH_T standard errors (then the best such one is served, and the
    status says so: a GP that loses is not served silently; a difference within the noise of
    a few days keeps the GP);
  - at a place with at least MIN_PLACE_ROWS held-out counts another forecaster is served
    instead where it was clearly better there (its mean squared-error difference is below
    -SWITCH_T standard errors: a place is not switched on noise);
  - a place never seen in training is always forecast by the GP (the baselines only know the
    places they saw).
Then the served forecast's interval width is calibrated on the held-out counts
(`calibration.calibrate`: dispersion and extra latent variance for 90% intervals holding
as near 90% of them as any width does). `refit` refits the baselines with their chosen
settings on all rows (the held-out days too) once the choices are made. `Serving` keeps
everything as plain arrays and a JSON-able report (`to_arrays`, `from_arrays`): a saved model
serves the same after loading. NumPy only.
"""
from typing import Dict, Optional, Tuple

import numpy as np

import traffic_gp.predictive as predictive
from traffic_gp.baselines import BinnedMean, FreMEn
from traffic_gp.calibration import Calibration, calibrate
from traffic_gp.observations import Observations
from traffic_gp.places import PlaceIndex

FORECASTERS = ("gp", "fremen", "binned_mean", "blend")
BLEND_WEIGHTS = (0.25, 0.5, 0.75)
MIN_PLACE_ROWS = 8
SWITCH_T = 2.0
GP_MARGIN = 0.9           # the GP or its blend must reach this share of the best baseline's RMSE
BASELINES = ("fremen", "binned_mean")
NOISE_KEEP = 0.01         # share of a squared error always kept when the count noise is taken out
BIN_MINUTES = (5, 10, 20, 30, 60, 120)
FREMEN_ORDERS = (0, 1, 2, 3, 4, 6, 8, 12, 16)
WEEKLY_DAYS = 14          # a weekly period is tried once the fitting rows span this many days


def baseline_periods(fit_days: int) -> Tuple[float, ...]:
    return (24.0, 168.0) if fit_days >= WEEKLY_DAYS else (24.0,)


def tune_baselines(places: PlaceIndex, fit: Observations, held: Observations, *,
                   periods, shortest_period: float) -> Dict[str, dict]:
    """Each baseline with its setting of least held-out squared error, fitted on `fit`:
    {name: {"model", "setting", "mse", "table"}}."""
    def mse(model) -> float:
        return float(np.mean((model.predict(held.x, held.y, held.t, held.exposure)
                              - held.count) ** 2))

    tuned = {}
    table = {}
    for period in periods:
        spectrum = FreMEn(places, period=period, shortest_period=shortest_period,
                          chunk=50000).fit(fit)
        for order in FREMEN_ORDERS:
            table[("fremen", period, order)] = mse(spectrum.set_order(order))
        for minutes in BIN_MINUTES:
            if minutes / 60.0 < period:
                table[("binned_mean", period, minutes)] = mse(
                    BinnedMean(places, bin_minutes=minutes, period=period).fit(fit))
    for name in ("fremen", "binned_mean"):
        mine = {key: value for key, value in table.items() if key[0] == name}
        _, period, setting = min(mine, key=mine.get)
        tuned[name] = {"model": make_baseline(name, period, setting, places, shortest_period,
                                              fit),
                       "setting": {"period": period,
                                   "order" if name == "fremen" else "bin_minutes": setting},
                       "mse": mine[(name, period, setting)],
                       "table": {f"{p:g}h/{s}": round(v, 6) for (_, p, s), v in mine.items()}}
    return tuned


def make_baseline(name: str, period: float, setting, places, shortest_period, rows):
    if name == "fremen":
        return FreMEn(places, order=setting, period=period, shortest_period=shortest_period,
                      chunk=50000).fit(rows)
    return BinnedMean(places, bin_minutes=setting, period=period).fit(rows)


def _t_stat(diff: np.ndarray, blocks: np.ndarray) -> float:
    """Mean over blocks of the summed differences, in standard errors (-inf: all negative)."""
    _, index = np.unique(blocks, return_inverse=True)
    sums = np.bincount(np.ravel(index), diff)
    if sums.size < 2:
        return 0.0
    spread = np.std(sums, ddof=1) / np.sqrt(sums.size)
    if spread == 0:
        return -np.inf if np.mean(sums) < 0 else 0.0
    return float(np.mean(sums) / spread)


def choose_default(errors: Dict[str, np.ndarray], blocks: np.ndarray) -> Tuple[str, dict]:
    """The GP, or the forecaster of least squared error among those clearly better than it
    (see the module); also each one's t statistic against the GP."""
    t_stats = {name: _t_stat(err - errors["gp"], blocks) for name, err in errors.items()
               if name != "gp"}
    better = [name for name, t in t_stats.items() if t < -SWITCH_T]
    if not better:
        return "gp", t_stats
    return min(better, key=lambda name: float(np.mean(errors[name]))), t_stats


def gp_ratio(rmse: Dict[str, float], noise: float = 0.0) -> Optional[float]:
    """RMSE of the better of the GP and its blend over the best baseline's (None without
    baselines), against the rates: `noise`, the counts' own variance about their rate (Poisson:
    their mean), is taken out of each mean squared error (at least NOISE_KEEP of it is kept), so
    that small counts, whose error is mostly their own noise, do not pull every ratio to 1."""
    def excess(name: str) -> float:
        square = rmse[name] ** 2
        return max(square - noise, NOISE_KEEP * square)

    base = [excess(name) for name in BASELINES if name in rmse]
    if not base:
        return None
    gp = min(excess(name) for name in ("gp", "blend") if name in rmse)
    return float(np.sqrt(gp / max(min(base), 1e-300)))


def _switches(errors: Dict[str, np.ndarray], place: np.ndarray, n_places: int,
              default: str) -> np.ndarray:
    """Per place: the forecaster served (index into FORECASTERS)."""
    choice = np.full(n_places, FORECASTERS.index(default), np.int64)
    best_t = np.zeros(n_places)
    ok = place >= 0
    n = np.bincount(place[ok], minlength=n_places).astype(float)
    for name, err in errors.items():
        if name == default:
            continue
        diff = (err - errors[default])[ok]
        total = np.bincount(place[ok], diff, n_places)
        square = np.bincount(place[ok], diff ** 2, n_places)
        mean = total / np.maximum(n, 1)
        var = np.maximum(square / np.maximum(n, 1) - mean ** 2, 1e-12) / np.maximum(n - 1, 1)
        t_stat = mean / np.sqrt(var)
        better = (n >= MIN_PLACE_ROWS) & (t_stat < -SWITCH_T) & (t_stat < best_t)
        choice[better], best_t[better] = FORECASTERS.index(name), t_stat[better]
    return choice


class Serving:
    """The served forecaster per place, the baselines and the calibrated interval width."""

    def __init__(self, places: PlaceIndex, choice: np.ndarray, default: str,
                 baselines: Dict[str, object], calibration: Optional[Calibration],
                 report: dict):
        self.places, self.choice, self.default = places, np.asarray(choice, np.int64), default
        self.baselines, self.calibration, self.report = baselines, calibration, report

    @property
    def dispersion(self) -> Optional[float]:
        return None if self.calibration is None else self.calibration.dispersion

    def served_index(self, x, y) -> np.ndarray:
        """Per point: index into FORECASTERS of the forecaster served there."""
        index = self.places.index_at(np.ravel(x), np.ravel(y))
        known = (index >= 0) & (index < self.choice.size)
        return np.where(known, self.choice[np.clip(index, 0, max(self.choice.size - 1, 0))], 0)

    def apply(self, x, y, t, mean, cov, full_cov: bool = False):
        """The GP's latent Gaussian (mean, variances or covariance) at places and times, with the
        baselines' log rates where they are served and the calibrated extra variance."""
        x, y, t = (np.ravel(v) for v in (x, y, t))
        mean, cov = np.array(mean, float), np.array(cov, float)
        who = self.served_index(x, y)
        blend = self.report.get("blend")
        for k, name in enumerate(FORECASTERS[1:], start=1):
            rows = np.nonzero(who == k)[0]
            base = blend["with"] if name == "blend" and blend else name
            if rows.size == 0 or base not in self.baselines:
                continue
            rate = self.baselines[base].predict(x[rows], y[rows], t[rows])
            var = np.zeros(rows.size)
            if name == "blend":        # w x GP + (1 - w) x baseline; the GP's share of its spread
                gp_var = np.diag(cov)[rows] if full_cov else cov[rows]
                w = blend["weight"]
                rate = w * predictive.expected_value(mean[rows], gp_var) + (1.0 - w) * rate
                var = w ** 2 * gp_var
            mean[rows] = np.log(np.maximum(rate, 1e-12)) - var / 2.0
            if full_cov:
                cov[rows, :], cov[:, rows] = 0.0, 0.0
                cov[rows, rows] = np.maximum(var, 1e-12)
            else:
                cov[rows] = np.maximum(var, 1e-12)
        if self.calibration is not None and self.calibration.latent_variance > 0:
            s = self.calibration.latent_variance
            mean = mean - s / 2.0
            cov = cov + s * np.eye(len(mean)) if full_cov else cov + s
        return mean, cov

    def refit(self, rows: Observations) -> "Serving":
        """Refit the baselines with their chosen settings on `rows` (places may be new)."""
        n_known = self.places.n_cells
        self.places.add(rows.x, rows.y)
        if self.places.n_cells > n_known:     # new places: the default forecaster
            extra = np.full(self.places.n_cells - n_known, FORECASTERS.index(self.default))
            self.choice = np.concatenate([self.choice, extra])
        for name in list(self.baselines):
            setting = self.report["baselines"][name]["setting"]
            self.baselines[name] = make_baseline(
                name, setting["period"], setting.get("order", setting.get("bin_minutes")),
                self.places, self.report["shortest_period"], rows)
        return self

    def verdict(self) -> str:
        """'' when the GP (or its blend) is served; else why the baselines are."""
        r = self.report
        if not r.get("gp_lost"):
            return ""
        return (f"GP {r['gp_ratio']:.2f}x the best baseline on the held-out days (needs "
                f"<= {r['gp_margin']:g}x): serving the baselines")

    def summary(self) -> str:
        """One line: what is served where, why, and the interval width."""
        r = self.report
        counts = ", ".join(f"{name} at {n}" for name, n in r["served_places"].items() if n)
        rmse = ", ".join(f"{name} {value:.4g}" for name, value in r["held_out_rmse"].items())
        blend = r.get("blend")
        what = r["default"] + (f" ({blend['weight']:g} GP + {1 - blend['weight']:g} "
                               f"{blend['with']})" if r["default"] == "blend" and blend else "")
        text = (f"serving {what} (held-out RMSE {rmse}); places: {counts}")
        if self.verdict():
            text = self.verdict() + "; " + text
        if self.calibration is not None:
            text += "; " + self.calibration.describe()
        return text

    # ---- persistence ------------------------------------------------------------------------
    def to_arrays(self) -> Dict[str, np.ndarray]:
        arrays = {"choice": self.choice}
        arrays.update({f"places.{k}": v for k, v in self.places.to_arrays().items()})
        for name, model in self.baselines.items():
            arrays.update({f"{name}.{k}": v for k, v in model.to_arrays().items()})
        return arrays

    def header(self) -> dict:
        return {"default": self.default, "baselines": sorted(self.baselines),
                "calibration": None if self.calibration is None else self.calibration.to_dict(),
                "report": self.report}

    @classmethod
    def from_arrays(cls, header: Optional[dict], arrays: Dict[str, np.ndarray]
                    ) -> Optional["Serving"]:
        if not header:
            return None
        from traffic_gp.baselines import _CellBaseline

        def part(prefix):
            return {k[len(prefix) + 1:]: v for k, v in arrays.items() if k.startswith(prefix + ".")}

        places = PlaceIndex.from_arrays(part("places"))
        baselines = {name: _CellBaseline.from_arrays(part(name), places)
                     for name in header["baselines"]}
        calibration = None if header["calibration"] is None \
            else Calibration.from_dict(header["calibration"])
        return cls(places, arrays["choice"], header["default"], baselines, calibration,
                   header["report"])


def build(gp_mean: np.ndarray, gp_var: np.ndarray, places: PlaceIndex, fit: Observations,
          held: Observations, *, fit_days: int, shortest_period: float, fallback: bool = True,
          calibrated: bool = True, seed: int = 0) -> Serving:
    """The served forecast from the GP's latent Gaussian at the held-out rows (`gp_mean`,
    `gp_var`, fitted on `fit`) and the baselines fitted on the same rows (see the module)."""
    errors = {"gp": (held.exposure * predictive.expected_value(gp_mean, gp_var)
                     - held.count) ** 2}
    tuned, baselines = {}, {}
    if fallback:
        tuned = tune_baselines(places, fit, held, periods=baseline_periods(fit_days),
                               shortest_period=shortest_period)
        for name, entry in tuned.items():
            baselines[name] = entry["model"]
            errors[name] = (entry["model"].predict(held.x, held.y, held.t, held.exposure)
                            - held.count) ** 2
    blend = None
    if tuned:
        base = min(tuned, key=lambda name: tuned[name]["mse"])
        gp_pred = held.exposure * predictive.expected_value(gp_mean, gp_var)
        base_pred = baselines[base].predict(held.x, held.y, held.t, held.exposure)
        blends = {w: (w * gp_pred + (1.0 - w) * base_pred - held.count) ** 2
                  for w in BLEND_WEIGHTS}
        weight = min(blends, key=lambda w: float(np.mean(blends[w])))
        errors["blend"], blend = blends[weight], {"with": base, "weight": weight}
    rmse = {name: float(np.sqrt(np.mean(err))) for name, err in errors.items()}
    place = places.index_at(held.x, held.y)
    default, t_stats = choose_default(errors, place * 100000 + np.floor(held.t / 24.0))
    ratio = gp_ratio(rmse, float(np.mean(held.count)))     # Poisson noise: the mean count
    gp_lost = ratio is not None and ratio > GP_MARGIN
    if gp_lost:               # only the baselines compete, per place too
        default = min(BASELINES, key=rmse.get)
        errors = {name: errors[name] for name in BASELINES}
    choice = _switches(errors, place, places.n_cells, default) if fallback \
        else np.zeros(places.n_cells, np.int64)
    report = {"held_out_rmse": rmse, "default": default, "shortest_period": shortest_period,
              "gp_ratio": ratio, "gp_margin": GP_MARGIN, "gp_lost": gp_lost,
              "blend": blend, "t_against_gp": {k: round(v, 2) for k, v in t_stats.items()},
              "baselines": {name: {"setting": entry["setting"], "table": entry["table"]}
                            for name, entry in tuned.items()},
              "served_places": {name: int(np.sum(choice == k))
                                for k, name in enumerate(FORECASTERS)}}
    serving = Serving(places, choice, default, baselines, None, report)
    mean, var = serving.apply(held.x, held.y, held.t, gp_mean, gp_var)
    served_pred = held.exposure * predictive.expected_value(mean, var)
    report["served_held_out_rmse"] = float(np.sqrt(np.mean((served_pred - held.count) ** 2)))
    if calibrated:
        serving.calibration = calibrate(held.count, mean, var, held.exposure, t=held.t,
                                        seed=seed)
    return serving
