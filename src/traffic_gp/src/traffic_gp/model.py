"""TrafficGP: where and when people are, learnt from counts with a sparse variational GP.

The latent f(x, y, t) is the log people density (per m^2) over the map and the time of day (or of
the week, `weekly=True`); counts are negative binomial with mean exposure * exp(f) and a trained
dispersion r (`likelihood="negbin"`, the default: real counts are overdispersed) or
Poisson(exposure * exp(f)) (`likelihood="poisson"`). Kernel: space x daily cycle, plus
(`hourly=True`) space x hourly cycle x daily envelope for the rush before the hour, plus
(`weekly=True`) space x weekly cycle. Training: minibatches, natural gradients for q(u) and Adam
for the hyperparameters, both step sizes lowered tenfold over the last 40 % of a `fit` (or
from the first validation plateau, whichever comes first).

`fit` holds out `validation_fraction` of the rows (at random, seeded): every `eval_every` steps
it records the ELBO on a fixed sample of training rows (`elbo_`, at `eval_steps_`) and the mean
negative log predictive density of the held-out rows (`validation_loss_`). When the validation
loss has not improved for `patience` evaluations after the warm-up, the step-size anneal (both
step sizes lowered tenfold over ANNEAL_SHARE of `n_steps`) starts there if it has not started yet
(`anneal_start_`: at full step size the minibatch jitter hides slow progress in the rate), and
`fit` stops at the first such plateau once the anneal is over. It returns the parameters of the
best evaluation (`best_step_`; of evaluations within 0.1 % of the best loss, the latest, the most
converged one): `n_steps` is a maximum, not a fixed cost.
Spatial inputs (`spatial_inputs`): "xy" puts the kernel on map coordinates, so a busy hall's
rate leaks through a wall into the room behind it; "geodesic" puts it on a
`geodesic.GeodesicEmbedding` of the map's free cells (distances through free space), made by
`fit` from the `cells` it is given and saved with the model; "auto" (the default) is geodesic
when `fit` is given the cells, xy otherwise. With geodesic inputs, parts of the free space
that no training row's place connects to (walled off from everything watched) are predicted
empty (`posterior.UNREACHABLE_DENSITY`).
Offset (`profile`): "none" (the default) has a constant mean; "daily", "daytype" or "weekly"
adds a per-place profile of the log rate (`rate_profile.RateProfile`: each place's own counts /
exposure per time bin, `profile_bin_minutes` wide, shrunk toward place rate x bin shape with
`profile_prior_exposure` of pseudo-exposure) to the latent, so the GP models the multiplicative
residual. `fit` builds it from the rows it trains on (not the held-out ones), `partial_fit` adds
the new rows to it, `save` keeps it. Where each place is watched often (fixed sensors, cells a
robot passes every day) the profile gives every place its own shape of the day at once, which
one smooth kernel over places far apart learns slowly.
`partial_fit` continues from the current state (warm start) with the new rows added to the data
(all rows, no hold-out, no early stopping). TensorFlow is imported on first use (by `gp_parts`).

The estimator owns its persistence: `save` writes its parameters, fitted state and (optionally)
training rows through the file format of `persistence`; the `load` classmethod rebuilds a fitted
estimator from such a file without training.
"""
import logging
import time
from typing import Optional

import numpy as np
from tqdm import tqdm

import traffic_gp.gp_parts as gp_parts
from robot_common.cells import HOURS_PER_WEEK, CellGrid
from traffic_gp.errors import ConfigError, ModelFormatError, NotFittedError
from traffic_gp.geodesic import DEFAULT_DIMS, GeodesicEmbedding
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_parameters, read_profile, read_spatial, write_model_file
from traffic_gp.posterior import LatentPredictions
from traffic_gp.rate_profile import KINDS as PROFILE_KINDS
from traffic_gp.rate_profile import RateProfile

log = logging.getLogger(__name__)

PARAMS = ("n_inducing", "spatial_lengthscale", "hourly", "weekly", "batch_size", "n_steps",
          "online_steps", "learning_rate", "natgrad_gamma", "train_inducing", "max_rows",
          "time_bin_minutes", "random_state", "likelihood", "validation_fraction", "eval_every",
          "patience", "spatial_inputs", "geodesic_dims", "profile", "profile_bin_minutes",
          "profile_prior_exposure")
SPATIAL_INPUTS = ("auto", "xy", "geodesic")
WARMUP_STEPS = 100
ADAM_WARMUP_STEPS = 50      # a new optimiser's (after fit or load) step size ramps up over these
EVAL_ROWS = 20000           # rows of the fixed ELBO sample and at most of the validation set
TIE_SHARE = 1e-3            # validation losses this close to the best count as ties
MIN_VALIDATION_ROWS = 50    # fewer held-out rows than this: no hold-out, no early stopping
ANNEAL_SHARE = 0.4


class TrafficGP(LatentPredictions):
    """sklearn-style estimator of people density; fitted attributes end in `_`.

    Args:
        n_inducing: inducing points (300-500 keeps a step fast and the rushes resolved).
        spatial_lengthscale: initial spatial lengthscale, metres.
        hourly: add the hourly cycle (rushes before the hour).
        weekly: model the week (weekends differ) instead of one cyclic day.
        batch_size, n_steps: minibatch size and steps of `fit`.
        online_steps: steps of each `partial_fit`.
        learning_rate: Adam's, for the hyperparameters; natgrad_gamma: natural-gradient step.
        train_inducing: also move the inducing points.
        max_rows: above this many stored rows, rows are merged per place and time bin of
            `time_bin_minutes` (`Observations.compress`, exact for Poisson counts).
        random_state: seeds the inducing-point choice, the hold-out and the minibatches.
        likelihood: "negbin" (overdispersed counts, trained dispersion) or "poisson".
        validation_fraction: share of the rows `fit` holds out for early stopping (0: none).
        eval_every: steps between evaluations (ELBO on a fixed sample, validation loss).
        patience: evaluations without a better validation loss before `fit` stops.
        spatial_inputs: "auto", "xy" or "geodesic" (see the module docstring).
        geodesic_dims: coordinates of the geodesic embedding.
        profile: "none", or the per-place offset's bins: "daily", "daytype" or "weekly".
        profile_bin_minutes: width of the offset's time bins.
        profile_prior_exposure: pseudo-exposure shrinking a sparse bin toward its prior.
        progress: show a tqdm bar while training.
    """

    def __init__(self, *, n_inducing: int = 400, spatial_lengthscale: float = 2.0,
                 hourly: bool = True, weekly: bool = False, batch_size: int = 1024,
                 n_steps: int = 1500, online_steps: int = 100, learning_rate: float = 0.02,
                 natgrad_gamma: float = 0.03, train_inducing: bool = True,
                 max_rows: int = 2_000_000, time_bin_minutes: float = 2.0,
                 random_state: Optional[int] = 0, likelihood: str = "negbin",
                 validation_fraction: float = 0.1, eval_every: int = 50, patience: int = 6,
                 spatial_inputs: str = "auto", geodesic_dims: int = DEFAULT_DIMS,
                 profile: str = "none", profile_bin_minutes: float = 60.0,
                 profile_prior_exposure: float = 1.0, progress: bool = False):
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
        self.progress = progress

    def get_params(self) -> dict:
        return {name: getattr(self, name) for name in PARAMS}

    @property
    def period(self) -> float:
        """Hours after which the modelled pattern repeats: a week or a day."""
        return HOURS_PER_WEEK if self.weekly else 24.0

    def _check_params(self) -> None:
        checks = {"n_inducing": self.n_inducing >= 1, "batch_size": self.batch_size >= 1,
                  "n_steps": self.n_steps >= 0, "online_steps": self.online_steps >= 0,
                  "spatial_lengthscale": self.spatial_lengthscale > 0,
                  "learning_rate": self.learning_rate > 0,
                  "natgrad_gamma": 0 < self.natgrad_gamma <= 1,
                  "max_rows": self.max_rows >= self.batch_size,
                  "time_bin_minutes": self.time_bin_minutes > 0,
                  "likelihood": self.likelihood in gp_parts.LIKELIHOODS,
                  "validation_fraction": 0 <= self.validation_fraction < 1,
                  "eval_every": self.eval_every >= 1, "patience": self.patience >= 1,
                  "spatial_inputs": self.spatial_inputs in SPATIAL_INPUTS,
                  "geodesic_dims": self.geodesic_dims >= 1,
                  "profile": self.profile in ("none",) + PROFILE_KINDS,
                  "profile_bin_minutes": self.profile_bin_minutes > 0
                  and 1440 % self.profile_bin_minutes == 0,
                  "profile_prior_exposure": self.profile_prior_exposure > 0}
        bad = [f"{name}={getattr(self, name)!r}" for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"bad TrafficGP parameters: {', '.join(bad)}")

    # ---- training -------------------------------------------------------------------------
    def fit(self, obs: Observations, n_steps: Optional[int] = None, *,
            cells: Optional[CellGrid] = None) -> "TrafficGP":
        """Start afresh on `obs` and train at most `n_steps` (default `self.n_steps`) steps,
        stopping early on the held-out rows (see the module docstring); `cells` (the map's
        cell grid) gives the geodesic spatial inputs."""
        self._check_params()
        if len(obs) == 0:
            raise NotFittedError("cannot fit on zero observations")
        if self.spatial_inputs == "geodesic" and cells is None:
            raise ConfigError("spatial_inputs='geodesic' needs the map: fit(obs, cells=CellGrid)")
        self.embedding_ = None
        if cells is not None and self.spatial_inputs != "xy":
            self.embedding_ = GeodesicEmbedding.from_cells(cells, dims=self.geodesic_dims,
                                                           seed=self.random_state or 0)
            self.embedding_.mark_observed(obs.x, obs.y)
        self._rng = np.random.default_rng(self.random_state)
        self.data_ = obs
        order = self._rng.permutation(len(obs))
        n_val = int(round(self.validation_fraction * len(obs)))
        if n_val < MIN_VALIDATION_ROWS:
            n_val = 0
        self._validation_rows = np.sort(order[:min(n_val, EVAL_ROWS)])
        self._train_rows = np.sort(order[n_val:])
        fit_part = obs.subset(self._train_rows)
        self.profile_ = None
        if self.profile != "none":
            self.profile_ = RateProfile(self.profile, self.profile_bin_minutes,
                                        self.profile_prior_exposure)
            self.profile_.update(fit_part.x, fit_part.y, fit_part.t, fit_part.exposure,
                                 fit_part.count)
        inputs = self._obs_inputs(fit_part)
        rate = max(fit_part.count.sum(), 0.5) / self._targets(fit_part)[:, 1].sum()
        self.model_ = gp_parts.build_model(
            self._initial_inducing(inputs), spatial_lengthscale=self.spatial_lengthscale,
            hourly=self.hourly, weekly=self.weekly, log_mean=float(np.log(rate)),
            num_data=len(fit_part), train_inducing=self.train_inducing,
            likelihood=self.likelihood)
        self.n_steps_, self.train_seconds_, self.compile_seconds_ = 0, 0.0, 0.0
        self.elbo_, self.eval_steps_, self.validation_loss_ = [], [], []
        self.best_step_, self.stopped_early_, self.anneal_start_ = None, False, None
        self._trainer = None
        self._train(self.n_steps if n_steps is None else n_steps, anneal=True,
                    early_stopping=len(self._validation_rows) > 0)
        self._train_rows = None            # partial_fit trains on every row
        return self

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
        self.model_.num_data.assign(float(len(self.data_)))
        return self._train(self.online_steps if n_steps is None else n_steps)

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

    def _train(self, n_steps: int, anneal: bool = False,
               early_stopping: bool = False) -> "TrafficGP":
        if self._trainer is None:
            self._trainer = gp_parts.Trainer(self.model_, learning_rate=self.learning_rate,
                                             gamma=self.natgrad_gamma)
            self._trainer_used, self._trainer_steps = False, 0
        rows = getattr(self, "_train_rows", None)
        data = self.data_ if rows is None else self.data_.subset(rows)
        inputs = self._obs_inputs(data)
        targets = self._targets(data)
        eval_rows = np.random.default_rng(self.random_state).permutation(len(data))[:EVAL_ROWS]
        eval_inputs, eval_targets = inputs[eval_rows], targets[eval_rows]
        if early_stopping:
            held_out = self.data_.subset(self._validation_rows)
            val_inputs = self._obs_inputs(held_out)
            val_targets = self._targets(held_out)
        size = min(self.batch_size, len(data))
        steps = range(n_steps)
        if self.progress and n_steps:
            steps = tqdm(steps, desc="training crowd GP", unit="step", mininterval=1.0)
        start = time.perf_counter()
        fresh = not self._trainer_used
        if fresh and n_steps:     # tracing the compiled functions takes seconds: timed apart
            self._trainer.elbo(inputs[:2], targets[:2])
        best, best_loss, done, improved_at = None, np.inf, 0, 0
        anneal_steps = max(int(round(ANNEAL_SHARE * n_steps)), 1)
        anneal_start = n_steps - anneal_steps if anneal else None
        for step in steps:
            annealed = 0.0
            if anneal_start is not None:
                annealed = min(max((step - anneal_start) / anneal_steps, 0.0), 1.0)
            self._set_rates(self.n_steps_ + step, annealed)
            batch = self._rng.integers(0, len(data), size)
            self._trainer.step(inputs[batch], targets[batch])
            self._trainer_steps += 1
            done = step + 1
            if fresh:
                self.compile_seconds_ += time.perf_counter() - start
                self._trainer_used, fresh = True, False
            if done % self.eval_every and step != n_steps - 1:
                continue
            self.eval_steps_.append(self.n_steps_ + done)
            self.elbo_.append(float(self._trainer.elbo(eval_inputs, eval_targets))
                              * len(data) / len(eval_rows))
            if not early_stopping:
                continue
            loss = -float(np.mean(self._trainer.log_density(val_inputs, val_targets)))
            self.validation_loss_.append(loss)
            if loss < best_loss:
                best_loss, improved_at = loss, self.n_steps_ + done
            if loss <= best_loss + TIE_SHARE * abs(best_loss):    # ties: the later state
                best = gp_parts.parameter_values(self.model_)
                self.best_step_ = self.n_steps_ + done
            elif (self.n_steps_ + done > WARMUP_STEPS
                  and self.n_steps_ + done - improved_at >= self.patience * self.eval_every):
                if anneal_start is not None and done < anneal_start:    # plateau: anneal now
                    anneal_start = done
                    anneal_steps = max(min(anneal_steps, n_steps - done), 1)
                elif anneal_start is None or done >= anneal_start + anneal_steps:
                    self.stopped_early_ = True
                    break
        if hasattr(steps, "close"):
            steps.close()
        if anneal_start is not None and anneal_start < done:
            self.anneal_start_ = self.n_steps_ + anneal_start
        self.n_steps_ += done
        if best is not None:
            gp_parts.assign_parameter_values(self.model_, best)
        self.train_seconds_ += time.perf_counter() - start
        if self.elbo_ and not np.isfinite(self.elbo_[-1]):
            log.warning("the ELBO is not finite after %d steps: lower learning_rate or "
                        "natgrad_gamma", self.n_steps_)
        return self

    def _set_rates(self, done: int, annealed: float) -> None:
        """Natural-gradient steps grow 100x over the first WARMUP_STEPS of training; both step
        sizes also grow linearly over the first ADAM_WARMUP_STEPS of a new optimiser (after
        `load`: a fresh Adam's first steps have the full step size in every direction whatever
        the gradient, and full natural-gradient steps on a minibatch would shake the model);
        over a fit's anneal (`annealed` goes from 0 to 1) both step sizes shrink 10x (less
        minibatch jitter)."""
        warm = 10.0 ** (-2.0 * (1.0 - done / WARMUP_STEPS)) if done < WARMUP_STEPS else 1.0
        adam_warm = min(1.0, (self._trainer_steps + 1) / ADAM_WARMUP_STEPS)
        warm = min(warm, adam_warm)         # a loaded model's first natural-gradient steps too
        anneal = 10.0 ** -annealed
        self._trainer.gamma.assign(self.natgrad_gamma * warm * anneal)
        self._trainer.adam.learning_rate.assign(self.learning_rate * anneal * adam_warm)

    # ---- prediction (the rest of the predictions: posterior.LatentPredictions) -------------
    def _fitted(self) -> bool:
        return hasattr(self, "model_")

    @property
    def dispersion_(self) -> Optional[float]:
        """The negative binomial's fitted dispersion r, or None for the Poisson likelihood."""
        return gp_parts.dispersion(self.model_)

    @property
    def n_rows_(self) -> int:
        """Training rows the model holds."""
        return len(self.data_)

    def _latent(self, inputs: np.ndarray, full_cov: bool = False):
        return gp_parts.predict_latent(self.model_, inputs, full_cov=full_cov)

    # ---- persistence ----------------------------------------------------------------------
    def save(self, path, *, include_data: bool = True, meta: Optional[dict] = None):
        """Write the fitted model to `path` (.npz, see `persistence`); returns the path.

        `include_data=False` leaves the training rows out (the file can predict, and
        `partial_fit` after loading then starts from the new rows only); `meta` (JSON-able,
        e.g. the map) comes back as `meta_` after `load`.
        """
        if not self._fitted():
            raise NotFittedError("cannot save a TrafficGP that is not fitted")
        header = {"params": self.get_params(), "n_steps": self.n_steps_,
                  "n_rows": len(self.data_), "elbo": self.elbo_[-1] if self.elbo_ else None,
                  "train_seconds": self.train_seconds_,
                  "best_step": getattr(self, "best_step_", None),
                  "libraries": gp_parts.library_versions(), "meta": meta or {}}
        spatial = None if self.embedding_ is None else self.embedding_.to_arrays()
        profile = None if self.profile_ is None else self.profile_.to_arrays()
        return write_model_file(path, header, gp_parts.parameter_values(self.model_),
                                self.data_ if include_data else None, spatial, profile)

    @classmethod
    def load(cls, path) -> "TrafficGP":
        """A fitted `TrafficGP` with the parameters saved in `path`; nothing is trained."""
        header, values, data = read_parameters(path, with_data=True)
        try:
            # files written before the likelihood was a parameter hold Poisson models
            estimator = cls(**dict({"likelihood": "poisson"}, **header["params"]))
            inducing = values[".inducing_variable.Z"]
        except (TypeError, KeyError) as err:
            raise ModelFormatError(f"{path}: the saved model lacks {err}") from err
        estimator.embedding_ = GeodesicEmbedding.from_arrays(read_spatial(path))
        estimator.profile_ = RateProfile.from_arrays(read_profile(path))
        if (estimator.profile_ is None) != (estimator.profile == "none"):
            raise ModelFormatError(f"{path}: profile={estimator.profile!r} but the file "
                                   f"{'lacks' if estimator.profile_ is None else 'holds'} one")
        estimator._restore(header, values, inducing, data)
        return estimator

    def _restore(self, header: dict, values: dict, inducing: np.ndarray,
                 data: Optional[Observations]) -> None:
        """The fitted state of a saved model (the file's header, parameters and rows)."""
        self._rng = np.random.default_rng(self.random_state)
        self.model_ = gp_parts.build_model(
            inducing, spatial_lengthscale=self.spatial_lengthscale, hourly=self.hourly,
            weekly=self.weekly, log_mean=0.0, num_data=header["n_rows"],
            train_inducing=self.train_inducing, likelihood=self.likelihood)
        gp_parts.assign_parameter_values(self.model_, values)
        self.data_ = data if data is not None else Observations.empty()
        self.n_steps_, self.train_seconds_ = header["n_steps"], header["train_seconds"]
        self.compile_seconds_ = 0.0
        self.elbo_ = [header["elbo"]] if header["elbo"] is not None else []
        self.eval_steps_ = [self.n_steps_] if self.elbo_ else []
        self.validation_loss_, self.best_step_ = [], header.get("best_step")
        self.stopped_early_, self.anneal_start_, self._train_rows = False, None, None
        self.meta_ = header["meta"]
        self._trainer = None
