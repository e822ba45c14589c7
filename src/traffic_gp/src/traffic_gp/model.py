"""TrafficGP: where and when people are, learnt from counts with a sparse variational GP.

The latent f(x, y, t) is the log people density (per m^2) over the map and the time of day (or of
the week, `weekly=True`); counts are Poisson(exposure * exp(f)) (`gp_parts.poisson_exposure`).
Kernel: space x daily cycle, plus (`hourly=True`) space x hourly cycle x daily envelope for the
rush before the hour, plus (`weekly=True`) space x weekly cycle. Training: minibatches, natural
gradients for q(u) and Adam for the hyperparameters, both step sizes lowered tenfold over the
last 40 % of a `fit`; `partial_fit` continues from the current state (warm start) with the new
rows added to the data. TensorFlow is imported on first use (by `gp_parts`).

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
from robot_common.cells import HOURS_PER_WEEK
from traffic_gp.errors import ConfigError, ModelFormatError, NotFittedError
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_parameters, write_model_file
from traffic_gp.posterior import LatentPredictions

log = logging.getLogger(__name__)

PARAMS = ("n_inducing", "spatial_lengthscale", "hourly", "weekly", "batch_size", "n_steps",
          "online_steps", "learning_rate", "natgrad_gamma", "train_inducing", "max_rows",
          "time_bin_minutes", "random_state")
WARMUP_STEPS = 100
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
        random_state: seeds the inducing-point choice and the minibatches.
        progress: show a tqdm bar while training.
    """

    def __init__(self, *, n_inducing: int = 400, spatial_lengthscale: float = 2.0,
                 hourly: bool = True, weekly: bool = False, batch_size: int = 1024,
                 n_steps: int = 1500, online_steps: int = 100, learning_rate: float = 0.02,
                 natgrad_gamma: float = 0.03, train_inducing: bool = True,
                 max_rows: int = 2_000_000, time_bin_minutes: float = 2.0,
                 random_state: Optional[int] = 0, progress: bool = False):
        self.n_inducing, self.spatial_lengthscale = n_inducing, spatial_lengthscale
        self.hourly, self.weekly = hourly, weekly
        self.batch_size, self.n_steps, self.online_steps = batch_size, n_steps, online_steps
        self.learning_rate, self.natgrad_gamma = learning_rate, natgrad_gamma
        self.train_inducing, self.max_rows = train_inducing, max_rows
        self.time_bin_minutes, self.random_state = time_bin_minutes, random_state
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
                  "time_bin_minutes": self.time_bin_minutes > 0}
        bad = [f"{name}={getattr(self, name)!r}" for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"bad TrafficGP parameters: {', '.join(bad)}")

    # ---- training -------------------------------------------------------------------------
    def fit(self, obs: Observations, n_steps: Optional[int] = None) -> "TrafficGP":
        """Start afresh on `obs` and train `n_steps` (default `self.n_steps`) steps."""
        self._check_params()
        if len(obs) == 0:
            raise NotFittedError("cannot fit on zero observations")
        self._rng = np.random.default_rng(self.random_state)
        self.data_ = obs
        inputs = obs.inputs(self.period)
        rate = max(obs.count.sum(), 0.5) / obs.exposure.sum()
        self.model_ = gp_parts.build_model(
            self._initial_inducing(inputs), spatial_lengthscale=self.spatial_lengthscale,
            hourly=self.hourly, weekly=self.weekly, log_mean=float(np.log(rate)),
            num_data=len(obs), train_inducing=self.train_inducing)
        self.n_steps_, self.elbo_, self.train_seconds_, self.compile_seconds_ = 0, [], 0.0, 0.0
        self._trainer = None
        return self._train(self.n_steps if n_steps is None else n_steps, anneal=True)

    def partial_fit(self, obs: Observations, n_steps: Optional[int] = None) -> "TrafficGP":
        """Add `obs` to the data and continue training from the current state (warm start)."""
        if not hasattr(self, "model_"):
            return self.fit(obs, n_steps)
        if len(obs):
            data = Observations.concat([self.data_, obs])
            if len(data) > self.max_rows:
                data = data.compress(self.time_bin_minutes / 60.0, self.period)
            self.data_ = data
            self.model_.num_data.assign(float(len(data)))
        return self._train(self.online_steps if n_steps is None else n_steps)

    def _initial_inducing(self, inputs: np.ndarray) -> np.ndarray:
        unique = np.unique(inputs, axis=0)
        if unique.shape[0] < self.n_inducing:
            raise ConfigError(f"{self.n_inducing} inducing points need at least as many distinct "
                              f"(place, time) rows; got {unique.shape[0]}")
        return unique[self._rng.choice(unique.shape[0], self.n_inducing, replace=False)]

    def _train(self, n_steps: int, anneal: bool = False) -> "TrafficGP":
        if self._trainer is None:
            self._trainer = gp_parts.Trainer(self.model_, learning_rate=self.learning_rate,
                                             gamma=self.natgrad_gamma)
            self._trainer_used = False
        inputs = self.data_.inputs(self.period)
        targets = np.column_stack([self.data_.count, self.data_.exposure])
        size = min(self.batch_size, len(self.data_))
        steps = range(n_steps)
        if self.progress and n_steps:
            steps = tqdm(steps, desc="training crowd GP", unit="step", mininterval=1.0)
        start = time.perf_counter()
        fresh = not self._trainer_used
        if fresh and n_steps:     # tracing the compiled functions takes seconds: timed apart
            self._trainer.elbo(inputs[:2], targets[:2])
        for step in steps:
            self._set_rates(self.n_steps_ + step, step / max(n_steps, 1) if anneal else 0.0)
            rows = self._rng.integers(0, len(self.data_), size)
            self._trainer.step(inputs[rows], targets[rows])
            if fresh:
                self.compile_seconds_ += time.perf_counter() - start
                self._trainer_used, fresh = True, False
            if (step + 1) % 100 == 0 or step == n_steps - 1:
                self.elbo_.append(float(self._trainer.elbo(inputs[rows], targets[rows])))
        self.n_steps_ += n_steps
        self.train_seconds_ += time.perf_counter() - start
        if self.elbo_ and not np.isfinite(self.elbo_[-1]):
            log.warning("the ELBO is not finite after %d steps: lower learning_rate or "
                        "natgrad_gamma", self.n_steps_)
        return self

    def _set_rates(self, done: int, progress: float) -> None:
        """Natural-gradient steps grow 100x over the first WARMUP_STEPS; in the last
        ANNEAL_SHARE of a fit both step sizes shrink 10x (less minibatch jitter at the end)."""
        warm = 10.0 ** (-2.0 * (1.0 - done / WARMUP_STEPS)) if done < WARMUP_STEPS else 1.0
        anneal = 1.0
        if progress > 1.0 - ANNEAL_SHARE:
            anneal = 10.0 ** (-(progress - 1.0 + ANNEAL_SHARE) / ANNEAL_SHARE)
        self._trainer.gamma.assign(self.natgrad_gamma * warm * anneal)
        self._trainer.adam.learning_rate.assign(self.learning_rate * anneal)

    # ---- prediction (the rest of the predictions: posterior.LatentPredictions) -------------
    def _fitted(self) -> bool:
        return hasattr(self, "model_")

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
                  "libraries": gp_parts.library_versions(), "meta": meta or {}}
        return write_model_file(path, header, gp_parts.parameter_values(self.model_),
                                self.data_ if include_data else None)

    @classmethod
    def load(cls, path) -> "TrafficGP":
        """A fitted `TrafficGP` with the parameters saved in `path`; nothing is trained."""
        header, values, data = read_parameters(path, with_data=True)
        try:
            estimator = cls(**header["params"])
            inducing = values[".inducing_variable.Z"]
        except (TypeError, KeyError) as err:
            raise ModelFormatError(f"{path}: the saved model lacks {err}") from err
        estimator._restore(header, values, inducing, data)
        return estimator

    def _restore(self, header: dict, values: dict, inducing: np.ndarray,
                 data: Optional[Observations]) -> None:
        """The fitted state of a saved model (the file's header, parameters and rows)."""
        self._rng = np.random.default_rng(self.random_state)
        self.model_ = gp_parts.build_model(
            inducing, spatial_lengthscale=self.spatial_lengthscale, hourly=self.hourly,
            weekly=self.weekly, log_mean=0.0, num_data=header["n_rows"],
            train_inducing=self.train_inducing)
        gp_parts.assign_parameter_values(self.model_, values)
        self.data_ = data if data is not None else Observations.empty()
        self.n_steps_, self.train_seconds_ = header["n_steps"], header["train_seconds"]
        self.compile_seconds_ = 0.0
        self.elbo_ = [header["elbo"]] if header["elbo"] is not None else []
        self.meta_ = header["meta"]
        self._trainer = None
