"""The tuned baselines alone: a forecast in about a second, served while the GP is chosen and
fitted.

`BaselineForecast.fit` holds out the most recent days (`validation.time_split`, as
`TrafficGP.fit` does), tunes FreMEn and the binned mean on them (`serving.tune_baselines`: the
period, order and bin width of least held-out squared error), keeps the better of the two,
calibrates its 90% intervals on the same days (`calibration.calibrate`) and refits it on all
rows. Without a hold-out it serves the binned mean of 60-minute bins of the day with Poisson
intervals, and says so. `partial_fit` adds rows to the chosen baseline's running sums (no new
tuning; its cost grows with the new rows only). It predicts through the same interface as
`TrafficGP` (`predict_latent`, `predict`, `predict_interval`, `sample_totals`, `status`), so the
node's queries and cost maps serve it unchanged; `status()` says it is not the GP. NumPy only.
"""
import time
from typing import Optional

import numpy as np

import traffic_gp.selection as selection
import traffic_gp.serving as serving
from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from traffic_gp.calibration import Calibration, calibrate
from traffic_gp.errors import NotFittedError
from traffic_gp.observations import Observations
from traffic_gp.places import PlaceIndex
from traffic_gp.posterior import LatentPredictions
from traffic_gp.validation import time_split

DEFAULT = ("binned_mean", {"period": 24.0, "bin_minutes": 60})   # without a hold-out
LOG_FLOOR = 1e-12


class BaselineForecast(LatentPredictions):
    """The better tuned baseline with calibrated intervals (see the module); fitted attributes
    end in `_`."""

    def __init__(self, *, validation_fraction: float = 0.2, calibrate: bool = True,
                 random_state: Optional[int] = 0):
        self.validation_fraction, self.calibrate = validation_fraction, calibrate
        self.random_state = random_state

    def fit(self, obs: Observations, cells: Optional[CellGrid] = None) -> "BaselineForecast":
        if len(obs) == 0:
            raise NotFittedError("cannot fit on zero observations")
        began = time.perf_counter()
        self.places_ = PlaceIndex.for_cells(cells).fit(obs.x, obs.y)
        self.shortest_period_ = selection.shortest_period(obs.t)
        self.calibration_: Optional[Calibration] = None
        self.held_out_rmse_, self.split_ = {}, None
        split = time_split(obs.t, self.validation_fraction)
        if split is None:
            self.name_, self.setting_ = DEFAULT[0], dict(DEFAULT[1])
        else:
            self.split_ = split.to_dict()
            fit_part, held = obs.subset(split.fit), obs.subset(split.held_out)
            fit_days = int(np.unique(np.floor(fit_part.t / 24.0)).size)
            tuned = serving.tune_baselines(
                self.places_, fit_part, held, periods=serving.baseline_periods(fit_days),
                shortest_period=self.shortest_period_)
            self.held_out_rmse_ = {name: float(np.sqrt(entry["mse"]))
                                   for name, entry in tuned.items()}
            self.name_ = min(tuned, key=lambda name: tuned[name]["mse"])
            self.setting_ = tuned[self.name_]["setting"]
            if self.calibrate:
                rate = tuned[self.name_]["model"].predict(held.x, held.y, held.t)
                self.calibration_ = calibrate(held.count, np.log(np.maximum(rate, LOG_FLOOR)),
                                              0.0, held.exposure, t=held.t,
                                              seed=self.random_state or 0)
        self._refit(obs)
        self.fit_seconds_ = time.perf_counter() - began
        return self

    def _refit(self, rows: Observations) -> None:
        setting = self.setting_
        self.baseline_ = serving.make_baseline(
            self.name_, setting["period"], setting.get("order", setting.get("bin_minutes")),
            self.places_, self.shortest_period_, rows)
        self.data_ = rows

    def partial_fit(self, obs: Observations, n_steps: Optional[int] = None) -> "BaselineForecast":
        """Add `obs` and refit the chosen baseline on all rows (`n_steps` is ignored)."""
        if not self._fitted():
            return self.fit(obs)
        if len(obs):
            self.places_.add(obs.x, obs.y)
            self.baseline_.update(obs)
            self.data_ = Observations.concat([self.data_, obs])
        return self

    # ---- what was fitted ------------------------------------------------------------------
    def _fitted(self) -> bool:
        return hasattr(self, "baseline_")

    @property
    def n_rows_(self) -> int:
        return len(self.data_)

    n_steps_ = 0            # no GP steps: the node's answers say "0 steps"
    serving_ = None

    @property
    def period(self) -> float:
        return float(self.setting_["period"])

    @property
    def count_dispersion_(self) -> Optional[float]:
        return None if self.calibration_ is None else self.calibration_.dispersion

    def _latent_at(self, x, y, t, full_cov: bool = False):
        """The baseline's log rate, widened by the calibrated extra variance."""
        if not self._fitted():
            raise NotFittedError("BaselineForecast is not fitted yet: call fit()")
        x, y, t = (np.ravel(v) for v in np.broadcast_arrays(
            *(np.asarray(v, dtype=float) for v in (x, y, t))))
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(t))):
            raise ConfigError("prediction inputs must be finite numbers")
        mean = np.log(np.maximum(self.baseline_.predict(x, y, t), LOG_FLOOR))
        extra = 0.0 if self.calibration_ is None else self.calibration_.latent_variance
        mean = mean - extra / 2.0
        cov = extra * np.eye(mean.size) if full_cov else np.full(mean.size, extra)
        return mean, cov

    def status(self) -> str:
        """What is served, why, and its intervals (one line); says it is not the GP."""
        if not self._fitted():
            return "not fitted"
        what = ", ".join(f"{k} {v:g}" for k, v in self.setting_.items())
        if self.held_out_rmse_:
            rmse = ", ".join(f"{k} {v:.4g}" for k, v in self.held_out_rmse_.items())
            why = f"the better tuned baseline on the held-out days (RMSE {rmse})"
        else:
            why = "no time-ordered hold-out to tune on (too few rows or days)"
        text = (f"baselines only, not the GP: model of {self.n_rows_} rows; serving "
                f"{self.name_} ({what}), {why}")
        if self.calibration_ is not None:
            return text + "; " + self.calibration_.describe()
        return text + "; 90% intervals: Poisson, not calibrated"
