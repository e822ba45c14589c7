"""TrafficGP: where and when people are, learnt from counts, never served worse than the simple
forecasters it carries.

The latent f(x, y, t) is the log people density (per m^2) over the map and the time of day (or
of the week); counts are Poisson(exposure * exp(f)) or negative binomial with that mean and a
trained dispersion. Kernel: space x daily cycle [+ space x hourly cycle x daily envelope: the
rush before the hour] [+ space x weekly cycle]; optionally a per-place rate profile as offset
(`rate_profile.RateProfile`: the GP models the residual). Spatial inputs are map coordinates
("xy") or walking distances through the map's free cells ("geodesic", `geodesic.py`).

`fit(obs, cells=None)`:
  1. holds out the most recent whole days (`validation.time_split`; `validation_fraction` of
     the days, the last week from four weeks on): every choice below is judged on forecasting
     those days from the days before them;
  2. chooses every setting left at "auto" (likelihood, profile, spatial inputs, kernel periods;
     `selection.py`) by short fits scored on the held-out days, then fits the winner at full
     size with early stopping and the step-size anneal on the held-out days (`training.py`);
  3. fits FreMEn and the binned mean on the same rows and serves, globally and per place,
     whichever forecast the held-out days better (`serving.py`, `fallback`);
  4. calibrates the served intervals' width on the held-out days (`calibration.py`,
     `calibrate`): 90% intervals holding as near 90% of the held-out counts as any width does;
  5. folds the held-out days in (the profile, `refit_steps` gentle steps of the GP, the
     baselines refitted on all rows).
`selection_`, `serving_.report`, `split_` and `status()` say what was chosen and why; the saved
model keeps them. Without a hold-out (too few rows or days, or `validation_fraction=0`) the
defaults of `selection.default_settings` are fitted on all rows and served as they are.
`partial_fit` continues from the current state (warm start) with the new rows added (no
hold-out, no re-selection; the baselines are refitted once the rows grew by a tenth).
TensorFlow is imported on first use (by `gp_parts`).
"""
import logging
import time
from typing import Optional

import numpy as np

import traffic_gp.gp_parts as gp_parts
import traffic_gp.selection as selection
import traffic_gp.serving as serving
from robot_common.cells import HOURS_PER_WEEK, CellGrid
from robot_common.errors import ConfigError
from traffic_gp.errors import ModelFormatError, NotFittedError
from traffic_gp.geodesic import DEFAULT_DIMS, GeodesicEmbedding
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_parameters, read_profile, read_serving, read_spatial, write_model_file
from traffic_gp.places import PlaceIndex
from traffic_gp.posterior import LatentPredictions
from traffic_gp.rate_profile import KINDS as PROFILE_KINDS
from traffic_gp.rate_profile import RateProfile
from traffic_gp.training import Training
from traffic_gp.validation import time_split

log = logging.getLogger(__name__)

AUTO = selection.AUTO
PARAMS = ("n_inducing", "spatial_lengthscale", "hourly", "weekly", "batch_size", "n_steps",
          "online_steps", "learning_rate", "natgrad_gamma", "train_inducing", "max_rows",
          "time_bin_minutes", "random_state", "likelihood", "validation_fraction", "eval_every",
          "patience", "spatial_inputs", "geodesic_dims", "profile", "profile_bin_minutes",
          "profile_prior_exposure", "screen_inducing", "screen_steps", "screen_rows",
          "fallback", "calibrate", "refit_steps")
SETTINGS = ("likelihood", "profile", "spatial_inputs", "weekly", "hourly")
SPATIAL_INPUTS = (AUTO, "xy", "geodesic")
REFIT_GROWTH = 1.1          # partial_fit refits the baselines once the rows grew this much


class TrafficGP(Training, LatentPredictions):
    """sklearn-style estimator of people density; fitted attributes end in `_`.

    Args:
        n_inducing: inducing points of the final fit (300-500 resolve the rushes).
        spatial_lengthscale: initial spatial lengthscale, metres.
        hourly: the hourly cycle (rushes before the hour): True, False or "auto".
        weekly: model the week (weekends differ) instead of one cyclic day, or "auto".
        batch_size, n_steps: minibatch size and (maximum) steps of the final fit.
        online_steps: steps of each `partial_fit`.
        learning_rate: Adam's, for the hyperparameters; natgrad_gamma: natural-gradient step.
        train_inducing: also move the inducing points.
        max_rows: above this many stored rows, rows are merged per place and time bin of
            `time_bin_minutes` (`Observations.compress`).
        random_state: seeds the inducing points, the minibatches and the samples.
        likelihood: "poisson", "negbin" or "auto".
        validation_fraction: share of the most recent whole days held out (0: none).
        eval_every: steps between evaluations; patience: evaluations without a better held-out
            loss before the anneal starts (or, after it, training stops).
        spatial_inputs: "auto", "xy" or "geodesic"; geodesic_dims: its coordinates.
        profile: "none", "daily", "daytype", "weekly" or "auto" (the per-place offset).
        profile_bin_minutes, profile_prior_exposure: the offset's bins and shrinkage.
        screen_inducing, screen_steps, screen_rows: size of each candidate's short fit.
        fallback: serve FreMEn or the binned mean where they forecast the held-out days better.
        calibrate: calibrate the interval width on the held-out days.
        refit_steps: steps folding the held-out days into the GP after the choices.
        (A `fit` of at most n steps screens and folds in at most n steps too.)
        progress: show a tqdm bar while training.
    """

    def __init__(self, *, n_inducing: int = 400, spatial_lengthscale: float = 2.0,
                 hourly=AUTO, weekly=AUTO, batch_size: int = 1024, n_steps: int = 1500,
                 online_steps: int = 100, learning_rate: float = 0.02,
                 natgrad_gamma: float = 0.03, train_inducing: bool = True,
                 max_rows: int = 2_000_000, time_bin_minutes: float = 2.0,
                 random_state: Optional[int] = 0, likelihood: str = AUTO,
                 validation_fraction: float = 0.2, eval_every: int = 50, patience: int = 6,
                 spatial_inputs: str = AUTO, geodesic_dims: int = DEFAULT_DIMS,
                 profile: str = AUTO, profile_bin_minutes: float = 60.0,
                 profile_prior_exposure: float = 1.0, screen_inducing: int = 100,
                 screen_steps: int = 200, screen_rows: int = 20000, fallback: bool = True,
                 calibrate: bool = True, refit_steps: int = 100, progress: bool = False):
        self.n_inducing, self.spatial_lengthscale = n_inducing, spatial_lengthscale
        self.hourly, self.weekly = hourly, weekly
        self.batch_size, self.n_steps, self.online_steps = batch_size, n_steps, online_steps
        self.learning_rate, self.natgrad_gamma = learning_rate, natgrad_gamma
        self.train_inducing, self.max_rows = train_inducing, max_rows
        self.time_bin_minutes, self.random_state = time_bin_minutes, random_state
        self.likelihood, self.validation_fraction = likelihood, validation_fraction
        self.eval_every, self.patience = eval_every, patience
        self.spatial_inputs, self.geodesic_dims = spatial_inputs, geodesic_dims
        self.profile, self.profile_bin_minutes = profile, profile_bin_minutes
        self.profile_prior_exposure = profile_prior_exposure
        self.screen_inducing, self.screen_steps = screen_inducing, screen_steps
        self.screen_rows, self.fallback, self.calibrate = screen_rows, fallback, calibrate
        self.refit_steps, self.progress = refit_steps, progress

    def get_params(self) -> dict:
        return {name: getattr(self, name) for name in PARAMS}

    def _setting(self, name: str):
        """A setting as fitted (`settings_`), else as given (may be "auto")."""
        settings = getattr(self, "settings_", None)
        return settings[name] if settings else getattr(self, name)

    @property
    def period(self) -> float:
        """Hours after which the modelled pattern repeats: a week or a day."""
        return HOURS_PER_WEEK if self._setting("weekly") is True else 24.0

    def _check_params(self) -> None:
        flag = (True, False, AUTO)
        checks = {"n_inducing": self.n_inducing >= 1, "batch_size": self.batch_size >= 1,
                  "n_steps": self.n_steps >= 0, "online_steps": self.online_steps >= 0,
                  "spatial_lengthscale": self.spatial_lengthscale > 0,
                  "learning_rate": self.learning_rate > 0,
                  "natgrad_gamma": 0 < self.natgrad_gamma <= 1,
                  "max_rows": self.max_rows >= self.batch_size,
                  "time_bin_minutes": self.time_bin_minutes > 0,
                  "likelihood": self.likelihood in gp_parts.LIKELIHOODS + (AUTO,),
                  "hourly": self.hourly in flag, "weekly": self.weekly in flag,
                  "validation_fraction": 0 <= self.validation_fraction < 1,
                  "eval_every": self.eval_every >= 1, "patience": self.patience >= 1,
                  "spatial_inputs": self.spatial_inputs in SPATIAL_INPUTS,
                  "geodesic_dims": self.geodesic_dims >= 1,
                  "profile": self.profile in ("none", AUTO) + PROFILE_KINDS,
                  "profile_bin_minutes": self.profile_bin_minutes > 0
                  and 1440 % self.profile_bin_minutes == 0,
                  "profile_prior_exposure": self.profile_prior_exposure > 0,
                  "screen_inducing": self.screen_inducing >= 1,
                  "screen_steps": self.screen_steps >= 0, "screen_rows": self.screen_rows >= 100,
                  "refit_steps": self.refit_steps >= 0}
        bad = [f"{name}={getattr(self, name)!r}" for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"bad TrafficGP parameters: {', '.join(bad)}")

    # ---- training -------------------------------------------------------------------------
    def fit(self, obs: Observations, n_steps: Optional[int] = None, *,
            cells: Optional[CellGrid] = None, warm_start: Optional[dict] = None) -> "TrafficGP":
        """Start afresh on `obs` (see the module docstring); at most `n_steps` (default
        `self.n_steps`) steps of the final fit; `cells` (the map's cell grid) makes the
        geodesic spatial inputs possible and the map's cells the baselines' places;
        `warm_start` (`gp_parts.parameter_values` of a model of the same settings) starts the
        kernel and likelihood from there (a refit on more rows)."""
        self._check_params()
        self._warm = warm_start
        if len(obs) == 0:
            raise NotFittedError("cannot fit on zero observations")
        if self.spatial_inputs == "geodesic" and cells is None:
            raise ConfigError("spatial_inputs='geodesic' needs the map: fit(obs, cells=CellGrid)")
        began = time.perf_counter()
        cap = self.n_steps if n_steps is None else n_steps
        self._screen_cap, self._refit_cap = min(self.screen_steps, cap), min(self.refit_steps, cap)
        self.settings_, self.serving_, self.split_ = None, None, None
        embedding = None
        if cells is not None and self.spatial_inputs != "xy":
            embedding = GeodesicEmbedding.from_cells(cells, dims=self.geodesic_dims,
                                                     seed=self.random_state or 0)
            embedding.mark_observed(obs.x, obs.y)
        self._embedding = embedding
        hourly = selection.hourly_cycle_visible(obs.t)
        split = time_split(obs.t, self.validation_fraction)
        if split is None:
            settings = selection.default_settings(self.get_params(), has_map=embedding is not None,
                                                  hourly=hourly)
            self.selection_ = selection.no_holdout_report(settings)
            self._fit_settings(settings, obs, None, n_steps)
        else:
            self.split_ = split.to_dict()
            log.info("traffic_gp: %s", split.describe())
            fit_part, held = obs.subset(split.fit), obs.subset(split.held_out)
            fit_days = int(np.unique(np.floor(fit_part.t / 24.0)).size)
            settings, self.selection_ = selection.choose(
                self._fit_candidate, self.get_params(), fit_part, held,
                has_map=embedding is not None, fit_days=fit_days, hourly=hourly,
                screen_rows=self.screen_rows, seed=self.random_state or 0)
            log.info("traffic_gp: %s; fitting it at full size", self.selection_["reason"])
            self._fit_settings(settings, fit_part, held, n_steps)
            if self.fallback or self.calibrate:
                log.info("traffic_gp: comparing with the baselines, calibrating the intervals")
                mean, var = self.predict_latent(held.x, held.y, held.t)
                self.serving_ = serving.build(
                    mean, var, PlaceIndex.for_cells(cells).fit(obs.x, obs.y), fit_part, held,
                    fit_days=fit_days, shortest_period=selection.shortest_period(obs.t),
                    fallback=self.fallback, calibrated=self.calibrate,
                    seed=self.random_state or 0)
            self._fold_in(held, obs)
        self.data_, self._embedding, self._warm = obs, None, None
        self._serving_rows = len(obs)
        self.fit_seconds_ = time.perf_counter() - began
        log.info("traffic_gp: %s", self.status())
        return self

    def _fit_candidate(self, settings: dict, rows: Observations,
                       held: Observations) -> "TrafficGP":
        """A short fit of one candidate setting (the screening of `selection.choose`)."""
        child = TrafficGP(**dict(self.get_params(), progress=False,
                                 n_inducing=min(self.screen_inducing, self.n_inducing),
                                 n_steps=self._screen_cap))
        child._embedding = self._embedding
        return child._fit_settings(settings, rows, held, None)

    def _fit_settings(self, settings: dict, rows: Observations, held: Optional[Observations],
                      n_steps: Optional[int]) -> "TrafficGP":
        """Build and train the GP of fixed `settings` on `rows`, stopping early on `held`."""
        self.settings_ = dict(settings)
        self.embedding_ = self._embedding if settings["spatial_inputs"] == "geodesic" else None
        self._rng = np.random.default_rng(self.random_state)
        self.data_ = rows
        self.profile_ = None
        if settings["profile"] != "none":
            self.profile_ = RateProfile(settings["profile"], self.profile_bin_minutes,
                                        self.profile_prior_exposure)
            self.profile_.update(rows.x, rows.y, rows.t, rows.exposure, rows.count)
        inputs = self._obs_inputs(rows)
        rate = max(rows.count.sum(), 0.5) / self._targets(rows)[:, 1].sum()
        self.model_ = gp_parts.build_model(
            self._initial_inducing(inputs), spatial_lengthscale=self.spatial_lengthscale,
            hourly=settings["hourly"], weekly=settings["weekly"], log_mean=float(np.log(rate)),
            num_data=len(rows), train_inducing=self.train_inducing,
            likelihood=settings["likelihood"])
        if getattr(self, "_warm", None):
            gp_parts.assign_hyperparameters(self.model_, self._warm)
        self.n_steps_, self.train_seconds_, self.compile_seconds_ = 0, 0.0, 0.0
        self.elbo_, self.eval_steps_, self.validation_loss_ = [], [], []
        self.best_step_, self.stopped_early_, self.anneal_start_ = None, False, None
        self._trainer = None
        return self._train(rows, self.n_steps if n_steps is None else n_steps, anneal=True,
                           held_out=held)

    def _fold_in(self, held: Observations, rows: Observations) -> None:
        """After the choices: the held-out days join the profile, the GP (gentle steps on all
        rows) and the baselines."""
        if self.profile_ is not None:
            self.profile_.update(held.x, held.y, held.t, held.exposure, held.count)
        self.model_.num_data.assign(float(len(rows)))
        if self._refit_cap:
            self._train(rows, self._refit_cap, rate_scale=0.1)
        if self.serving_ is not None:
            self.serving_.refit(rows)

    def partial_fit(self, obs: Observations, n_steps: Optional[int] = None) -> "TrafficGP":
        """Add `obs` to the data and continue training from the current state (warm start)."""
        if not hasattr(self, "model_"):
            return self.fit(obs, n_steps)
        if len(obs):
            if self.embedding_ is not None:
                self.embedding_.mark_observed(obs.x, obs.y)
            if self.profile_ is not None:
                self.profile_.update(obs.x, obs.y, obs.t, obs.exposure, obs.count)
            data = Observations.concat([self.data_, obs])
            if len(data) > self.max_rows:
                data = data.compress(self.time_bin_minutes / 60.0, self.period)
            self.data_ = data
            if self.serving_ is not None and len(data) >= REFIT_GROWTH * self._serving_rows:
                self.serving_.refit(data)
                self._serving_rows = len(data)
        self.model_.num_data.assign(float(len(self.data_)))
        return self._train(self.data_, self.online_steps if n_steps is None else n_steps)

    def _obs_inputs(self, obs: Observations) -> np.ndarray:
        return self.model_inputs(obs.x, obs.y, obs.t)

    def _targets(self, obs: Observations) -> np.ndarray:
        """[count, exposure] columns of the likelihood; with a profile, the exposure times the
        profile's rate (the offset of the log rate: the GP sees the residual)."""
        exposure = obs.exposure
        if self.profile_ is not None:
            exposure = exposure * np.exp(self.profile_.log_rate(obs.x, obs.y, obs.t))
        return np.column_stack([obs.count, exposure])

    def _initial_inducing(self, inputs: np.ndarray) -> np.ndarray:
        unique = np.unique(inputs, axis=0)
        if unique.shape[0] < self.n_inducing:
            raise ConfigError(f"{self.n_inducing} inducing points need at least as many distinct "
                              f"(place, time) rows; got {unique.shape[0]}")
        return unique[self._rng.choice(unique.shape[0], self.n_inducing, replace=False)]

    # ---- what was fitted ------------------------------------------------------------------
    def _fitted(self) -> bool:
        return hasattr(self, "model_")

    @property
    def dispersion_(self) -> Optional[float]:
        """The trained negative-binomial dispersion r, or None for the Poisson likelihood."""
        return gp_parts.dispersion(self.model_)

    @property
    def n_rows_(self) -> int:
        """Training rows the model holds."""
        return len(self.data_)

    def _latent(self, inputs: np.ndarray, full_cov: bool = False):
        return gp_parts.predict_latent(self.model_, inputs, full_cov=full_cov)

    def status(self) -> str:
        """What was chosen and why, and what is served (one line, for `~status` and logs)."""
        if not self._fitted():
            return "not fitted"
        text = (f"model of {self.n_rows_} rows, {self.n_steps_} steps; "
                f"{getattr(self, 'selection_', {}).get('reason', 'settings as given')}")
        if self.serving_ is not None:
            text += "; " + self.serving_.summary()
        else:
            why = ("no hold-out to compare or calibrate on" if self.split_ is None
                   else "fallback and calibration off")
            text += f"; serving the GP as trained ({why})"
        return text

    # ---- persistence ----------------------------------------------------------------------
    def save(self, path, *, include_data: bool = True, meta: Optional[dict] = None):
        """Write the fitted model to `path` (.npz, see `persistence`); returns the path.

        `include_data=False` leaves the training rows out (the file can predict, and
        `partial_fit` after loading then starts from the new rows only); `meta` (JSON-able,
        e.g. the map) comes back as `meta_` after `load`.
        """
        if not self._fitted():
            raise NotFittedError("cannot save a TrafficGP that is not fitted")
        header = {"params": self.get_params(), "settings": self.settings_,
                  "selection": getattr(self, "selection_", None), "split": self.split_,
                  "serving": None if self.serving_ is None else self.serving_.header(),
                  "n_steps": self.n_steps_, "n_rows": len(self.data_),
                  "elbo": self.elbo_[-1] if self.elbo_ else None,
                  "train_seconds": self.train_seconds_, "best_step": self.best_step_,
                  "libraries": gp_parts.library_versions(), "meta": meta or {}}
        spatial = None if self.embedding_ is None else self.embedding_.to_arrays()
        profile = None if self.profile_ is None else self.profile_.to_arrays()
        served = None if self.serving_ is None else self.serving_.to_arrays()
        return write_model_file(path, header, gp_parts.parameter_values(self.model_),
                                self.data_ if include_data else None, spatial, profile, served)

    @classmethod
    def load(cls, path) -> "TrafficGP":
        """A fitted `TrafficGP` with the parameters saved in `path`; nothing is trained."""
        header, values, data = read_parameters(path, with_data=True)
        try:
            params = {k: v for k, v in header["params"].items() if k in PARAMS}
            estimator = cls(**params)
            inducing = values[".inducing_variable.Z"]
        except (TypeError, KeyError) as err:
            raise ModelFormatError(f"{path}: the saved model lacks {err}") from err
        estimator.embedding_ = GeodesicEmbedding.from_arrays(read_spatial(path))
        estimator.profile_ = RateProfile.from_arrays(read_profile(path))
        estimator.settings_ = saved_settings(header, estimator.embedding_ is not None)
        if (estimator.profile_ is None) != (estimator.settings_["profile"] == "none"):
            raise ModelFormatError(f"{path}: profile={estimator.settings_['profile']!r} but the "
                                   f"file {'lacks' if estimator.profile_ is None else 'holds'} one")
        estimator.serving_ = serving.Serving.from_arrays(header.get("serving"),
                                                         read_serving(path))
        estimator._restore(header, values, inducing, data)
        return estimator

    def _restore(self, header: dict, values: dict, inducing: np.ndarray,
                 data: Optional[Observations]) -> None:
        """The fitted state of a saved model (the file's header, parameters and rows)."""
        self._rng = np.random.default_rng(self.random_state)
        settings = self.settings_
        self.model_ = gp_parts.build_model(
            inducing, spatial_lengthscale=self.spatial_lengthscale, hourly=settings["hourly"],
            weekly=settings["weekly"], log_mean=0.0, num_data=header["n_rows"],
            train_inducing=self.train_inducing, likelihood=settings["likelihood"])
        gp_parts.assign_parameter_values(self.model_, values)
        self.data_ = data if data is not None else Observations.empty()
        self._serving_rows = len(self.data_)
        self.n_steps_, self.train_seconds_ = header["n_steps"], header["train_seconds"]
        self.compile_seconds_ = 0.0
        self.elbo_ = [header["elbo"]] if header["elbo"] is not None else []
        self.eval_steps_ = [self.n_steps_] if self.elbo_ else []
        self.validation_loss_, self.best_step_ = [], header.get("best_step")
        self.stopped_early_, self.anneal_start_ = False, None
        self.selection_, self.split_ = header.get("selection") or {}, header.get("split")
        self.meta_ = header["meta"]
        self._trainer = None


def saved_settings(header: dict, geodesic: bool) -> dict:
    """The fitted settings of a model file (files of earlier releases: their parameters, which
    were always concrete; their likelihood was Poisson when not recorded)."""
    if header.get("settings"):
        return dict(header["settings"])
    params = header.get("params", {})
    return {"likelihood": params.get("likelihood", "poisson"),
            "profile": params.get("profile", "none"),
            "spatial_inputs": "geodesic" if geodesic else "xy",
            "weekly": bool(params.get("weekly", False)),
            "hourly": bool(params.get("hourly", True))}
