"""Predictions from a crowd model in NumPy, and a saved model's posterior without TensorFlow.

Importing TensorFlow and GPflow takes several seconds, and a node that loads a saved model only to
answer queries needs neither. `PosteriorSnapshot.load(path)` reads the parameters a `TrafficGP`
saved (`persistence.read_parameters`), maps them to their constrained values as GPflow does
(softplus for the positive ones, TensorFlow Probability's fill_triangular for q_sqrt) and
predicts the latent log density as the whitened SVGP's `predict_f` does; a negative-binomial
model's dispersion (`.likelihood.dispersion`, softplus) comes along, so count intervals and
log-likelihoods are those of the saved likelihood. A model with map-aware spatial inputs keeps
its `geodesic.GeodesicEmbedding` in the file (`persistence.read_spatial`): the snapshot maps
places to the same inputs; a model with a rate profile (`rate_profile.RateProfile`, the per-place
offset of the log rate) keeps it in the file too (`persistence.read_profile`) and the snapshot
adds it as the model does; what the model serves besides its GP (`serving.Serving`: baselines
at the places where they forecast better, the calibrated interval width) comes along too
(`persistence.read_serving`). `LatentPredictions` holds the predictions both `TrafficGP` and the
snapshot derive from the latent Gaussian.
"""
import re
from typing import Dict, List, Optional, Tuple

import numpy as np

import traffic_gp.predictive as predictive
from robot_common.cells import HOURS_PER_WEEK
from robot_common.errors import ConfigError
from traffic_gp.errors import ModelFormatError, NotFittedError
from traffic_gp.geodesic import GeodesicEmbedding
from traffic_gp.persistence import read_parameters, read_profile, read_serving, read_spatial
from traffic_gp.rate_profile import RateProfile
from traffic_gp.serving import Serving

JITTER = 1e-6          # GPflow's default jitter on K(Z, Z)
UNREACHABLE_DENSITY = 1e-6   # people per m^2 where no watched place connects (geodesic inputs)
CHUNK = 20000          # prediction rows per block (memory stays small)


def latent_grid(predict_latent, x, y, times) -> Tuple[np.ndarray, np.ndarray]:
    """`predict_latent(x, y, t)` at every place (x, y) at each of `times`, one call: mean and
    variance, arrays of shape (len(times), len(x))."""
    x, y, times = (np.ravel(np.asarray(v, dtype=float)) for v in (x, y, times))
    mean, var = predict_latent(np.tile(x, times.size), np.tile(y, times.size),
                               np.repeat(times, x.size))
    return np.reshape(mean, (times.size, x.size)), np.reshape(var, (times.size, x.size))


class LatentPredictions:
    """Predictions from the Gaussian over the log density f(x, y, t); subclasses provide
    `_latent(inputs, full_cov)`, `_fitted()`, `period`, `random_state`, `dispersion_`
    (None for Poisson counts, r of the negative binomial otherwise), `embedding_` (None:
    the kernel works on x, y; else the `GeodesicEmbedding` giving the spatial inputs; places
    it finds unreachable from every watched place get the log of UNREACHABLE_DENSITY, with no
    uncertainty: nobody can walk there), `profile_` (None, or the `RateProfile` whose log
    rate is added to the GP's latent mean: the GP then models the residual) and `serving_`
    (None, or the `Serving` that puts the baselines' log rates where they are served and widens
    the Gaussian by the calibrated variance; its dispersion is then the count noise)."""

    embedding_: Optional[GeodesicEmbedding] = None
    profile_: Optional[RateProfile] = None
    serving_: Optional[Serving] = None

    @property
    def count_dispersion_(self) -> Optional[float]:
        """The count noise of the served predictions: the calibrated dispersion (None:
        Poisson) when the interval width was calibrated, else the trained one."""
        if self.serving_ is not None and self.serving_.calibration is not None:
            return self.serving_.dispersion
        return self.dispersion_

    def model_inputs(self, x, y, t) -> np.ndarray:
        """The GP's input rows for places (x, y) and times t: the spatial columns (x, y, or the
        geodesic embedding of the place's cell), then the time modulo the period."""
        x, y, t = (np.ravel(v) for v in np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                                              for v in (x, y, t))))
        space = np.column_stack([x, y]) if self.embedding_ is None \
            else self.embedding_.transform(x, y)
        return np.column_stack([space, np.mod(t, self.period)])

    def _inputs(self, x, y, t) -> np.ndarray:
        if not self._fitted():
            raise NotFittedError(f"{type(self).__name__} is not fitted yet: call fit() or load a model")
        x, y, t = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, y, t)))
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(t))):
            raise ConfigError("prediction inputs must be finite numbers")
        return self.model_inputs(x, y, t)

    def _latent_at(self, x, y, t, full_cov: bool = False):
        """`_latent` at places and times, with the unreachable places set (see the class)."""
        mean, cov = self._latent(self._inputs(x, y, t), full_cov=full_cov)
        return self._served(x, y, t, mean, cov, full_cov)

    def _served(self, x, y, t, mean, cov, full_cov: bool):
        """The GP's latent Gaussian at places and times with the rate profile, the unreachable
        places and the serving applied (see the class)."""
        x, y, t = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, y, t)))
        if self.profile_ is not None:
            mean = mean + self.profile_.log_rate(x, y, t)
        if self.embedding_ is not None:
            mean, cov = self._unreachable(x, y, mean, cov, full_cov)
        if self.serving_ is not None:
            mean, cov = self.serving_.apply(x, y, t, mean, cov, full_cov)
        return mean, cov

    def _unreachable(self, x, y, mean, cov, full_cov: bool):
        away = self.embedding_.unreachable(x, y)
        if away.any():
            mean, cov = mean.copy(), cov.copy()
            mean[away] = np.log(UNREACHABLE_DENSITY)
            if full_cov:
                cov[away, :], cov[:, away] = 0.0, 0.0
                cov[away, away] = 1e-12
            else:
                cov[away] = 1e-12
        return mean, cov

    def predict_latent(self, x, y, t) -> Tuple[np.ndarray, np.ndarray]:
        """Mean and variance of the log density at places (x, y) and times t (hours of week)."""
        return self._latent_at(x, y, t)

    def predict_latent_grid(self, x, y, times) -> Tuple[np.ndarray, np.ndarray]:
        """`predict_latent` at every place (x, y) at each of `times`: mean and variance, arrays
        of shape (len(times), len(x))."""
        return latent_grid(self.predict_latent, x, y, times)

    def predict(self, x, y, t, exposure=1.0) -> np.ndarray:
        """Expected people counts (density for exposure 1 m^2)."""
        mean, var = self.predict_latent(x, y, t)
        return np.asarray(exposure) * predictive.expected_value(mean, var)

    def predict_std(self, x, y, t, exposure=1.0) -> np.ndarray:
        """Uncertainty (standard deviation) of the expected count."""
        mean, var = self.predict_latent(x, y, t)
        return np.asarray(exposure) * predictive.expected_std(mean, var)

    def predict_interval(self, x, y, t, exposure=1.0, level: float = 0.9):
        """Central `level` predictive interval of the count itself (model + count noise)."""
        mean, var = self.predict_latent(x, y, t)
        return predictive.interval(level, mean, var, exposure, self.count_dispersion_)

    def sample_totals(self, x, y, t, exposure, n_samples: int = 500) -> np.ndarray:
        """Samples of the summed expected count over many cells at one time (joint posterior)."""
        mean, cov = self._latent_at(x, y, t, full_cov=True)
        chol = np.linalg.cholesky(cov + 1e-8 * np.eye(cov.shape[0]))
        rng = np.random.default_rng(self.random_state)
        f = mean[None, :] + rng.standard_normal((n_samples, mean.size)) @ chol.T
        return np.exp(f) @ np.broadcast_to(np.asarray(exposure, float), mean.shape)

    def score(self, obs) -> float:
        """Mean held-out log predictive density of the counts (higher is better)."""
        mean, var = self.predict_latent(obs.x, obs.y, obs.t)
        return float(np.mean(predictive.log_density(obs.count, mean, var, obs.exposure,
                                                    self.count_dispersion_)))


def softplus(x: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, x)


def fill_triangular(vector: np.ndarray) -> np.ndarray:
    """Lower-triangular n x n matrix from its n(n+1)/2 entries, in the order of
    tfp.math.fill_triangular (GPflow's bijector for q_sqrt)."""
    m = vector.shape[-1]
    n = int(np.sqrt(0.25 + 2.0 * m) - 0.5)
    if n * (n + 1) // 2 != m:
        raise ModelFormatError(f"q_sqrt has {m} entries, not a triangular number")
    tail = vector[..., m - (n * n - m):]
    full = np.concatenate([tail, vector[..., ::-1]], axis=-1).reshape(vector.shape[:-1] + (n, n))
    return np.tril(full)


class _Factor:
    """One factor of a product kernel: squared exponential over the space columns (all but the
    last; one lengthscale per column, or one shared) or periodic over the time (the last)."""

    def __init__(self, variance: float, lengthscales: np.ndarray, period: float = 0.0):
        self.variance, self.lengthscales, self.period = variance, np.atleast_1d(lengthscales), period

    def matrix(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if self.period:        # GPflow Periodic(SquaredExponential) on the time column
            r = np.pi * (a[:, -1, None] - b[None, :, -1]) / self.period
            return self.variance * np.exp(-0.5 * (np.sin(r) / self.lengthscales[0]) ** 2)
        scales = np.broadcast_to(self.lengthscales, (a.shape[1] - 1,))
        sq = sum(((a[:, d, None] - b[None, :, d]) / scales[d]) ** 2 for d in range(len(scales)))
        return self.variance * np.exp(-0.5 * sq)


class PosteriorSnapshot(LatentPredictions):
    """A saved TrafficGP's posterior, predicting in NumPy; loads in a fraction of a second.

    It answers every prediction a fitted TrafficGP answers (the same numbers, to rounding); to
    train further, load the file as a TrafficGP (which imports TensorFlow).
    """

    def __init__(self, header: dict, values: Dict[str, np.ndarray], path: str = "",
                 spatial: Optional[Dict[str, np.ndarray]] = None,
                 profile: Optional[Dict[str, np.ndarray]] = None,
                 served: Optional[Dict[str, np.ndarray]] = None):
        params = header["params"]
        settings = header.get("settings") or params
        self.embedding_ = GeodesicEmbedding.from_arrays(spatial)
        self.profile_ = RateProfile.from_arrays(profile or {})
        self.serving_ = Serving.from_arrays(header.get("serving"), served or {})
        self.path, self.header = path, header
        self.weekly = settings.get("weekly", False) is True
        self.random_state = params.get("random_state", 0)
        self.n_steps_, self.n_rows_ = header.get("n_steps", 0), header.get("n_rows", 0)
        try:
            self.terms = _kernel_terms(values)
            self.constant = float(values[".mean_function.c"].ravel()[0])
            self.inducing = np.asarray(values[".inducing_variable.Z"], float)
            columns = 3 if self.embedding_ is None else self.embedding_.dims + 1
            if self.inducing.ndim != 2 or self.inducing.shape[1] != columns:
                raise ValueError(f"inducing points of shape {self.inducing.shape} for "
                                 f"{columns} input columns")
            q_mu = np.asarray(values[".q_mu"], float)[:, 0]
            q_sqrt = fill_triangular(np.asarray(values[".q_sqrt"], float))[0]
            self.dispersion_ = None
            if settings.get("likelihood", "poisson") == "negbin":
                self.dispersion_ = float(softplus(np.asarray(values[".likelihood.dispersion"],
                                                             float)))
        except (KeyError, IndexError, ValueError) as err:
            raise ModelFormatError(f"{path or 'model'}: unexpected saved parameters ({err})") from err
        kuu = self._kernel(self.inducing, self.inducing) + JITTER * np.eye(len(self.inducing))
        chol = np.linalg.cholesky(kuu)
        inv_chol_t = np.linalg.inv(chol).T                 # L^-T
        self._mean_weights = inv_chol_t @ q_mu              # mean = Kzx^T L^-T q_mu
        self._var_form = inv_chol_t @ (q_sqrt @ q_sqrt.T - np.eye(len(q_mu))) @ inv_chol_t.T

    @classmethod
    def load(cls, path) -> "PosteriorSnapshot":
        """The posterior of a model file written by `TrafficGP.save` (no TensorFlow)."""
        header, values, _ = read_parameters(path)
        return cls(header, values, str(path), read_spatial(path), read_profile(path),
                   read_serving(path))

    def status(self) -> str:
        """What the saved model chose and serves (as `TrafficGP.status`)."""
        reason = (self.header.get("selection") or {}).get("reason", "settings as given")
        text = f"model of {self.n_rows_} rows, {self.n_steps_} steps; {reason}"
        if self.serving_ is not None:
            return text + "; " + self.serving_.summary()
        why = ("no hold-out to compare or calibrate on" if self.header.get("split") is None
               else "fallback and calibration off")
        return text + f"; serving the GP as trained ({why})"

    @property
    def period(self) -> float:
        return HOURS_PER_WEEK if self.weekly else 24.0

    def _fitted(self) -> bool:
        return True

    def _kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        total = np.zeros((len(a), len(b)))
        for factors in self.terms:
            product = np.ones_like(total)
            for factor in factors:
                product *= factor.matrix(a, b)
            total += product
        return total

    def _latent(self, inputs: np.ndarray, full_cov: bool = False):
        if full_cov:
            kzx = self._kernel(self.inducing, inputs)
            cov = self._kernel(inputs, inputs) + kzx.T @ self._var_form @ kzx
            return self.constant + kzx.T @ self._mean_weights, cov
        parts = [self._moments(self._kernel(self.inducing, inputs[start:start + CHUNK]))
                 for start in range(0, max(len(inputs), 1), CHUNK)]
        return tuple(np.concatenate(values) for values in zip(*parts))

    def _moments(self, kzx: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Mean and variance of the latent at the inputs whose K(Z, X) is `kzx`."""
        prior_var = sum(np.prod([f.variance for f in factors]) for factors in self.terms)
        variance = prior_var + np.einsum("ij,ij->j", kzx, self._var_form @ kzx)
        return self.constant + kzx.T @ self._mean_weights, np.maximum(variance, 1e-12)

    def _term_parts(self, inputs: np.ndarray, periodic: bool) -> List[np.ndarray]:
        """Per kernel term, the product of its time factors (`periodic`) or of its space factors
        between the inducing points and `inputs`."""
        parts = []
        for factors in self.terms:
            product = np.ones((len(self.inducing), len(inputs)))
            for factor in factors:
                if bool(factor.period) == periodic:
                    product *= factor.matrix(self.inducing, inputs)
            parts.append(product)
        return parts

    def predict_latent_grid(self, x, y, times) -> Tuple[np.ndarray, np.ndarray]:
        """As `LatentPredictions.predict_latent_grid`, faster: each kernel factor is over the
        space or over the time, so the space factors are computed once per place, not once per
        place and time."""
        x, y, times = (np.ravel(np.asarray(v, dtype=float)) for v in (x, y, times))
        space = self._inputs(x, y, np.zeros(x.size))
        if not np.all(np.isfinite(times)):
            raise ConfigError("prediction inputs must be finite numbers")
        clock = np.zeros((times.size, self.inducing.shape[1]))    # the time column only is used
        clock[:, -1] = np.mod(times, self.period)
        clock_parts = self._term_parts(clock, periodic=True)
        mean, var = np.empty((2, times.size, x.size))
        step = CHUNK // (4 * len(self.terms)) + 1     # the terms' space parts stay small
        for start in range(0, x.size, step):
            space_parts = self._term_parts(space[start:start + step], periodic=False)
            for k in range(times.size):
                kzx = sum(part * when[:, k, None] for part, when in zip(space_parts, clock_parts))
                mean[k, start:start + step], var[k, start:start + step] = self._moments(kzx)
        mean, var = self._served(np.tile(x, times.size), np.tile(y, times.size),
                                 np.repeat(times, x.size), mean.ravel(), var.ravel(), False)
        return mean.reshape(times.size, x.size), var.reshape(times.size, x.size)


def _kernel_terms(values: Dict[str, np.ndarray]) -> List[List[_Factor]]:
    """The sum-of-products kernel (see gp_parts.build_kernel) from the saved parameter paths."""
    pattern = re.compile(r"^\.kernel((?:\.kernels\[\d+\])*)\.(base_kernel\.)?(variance|lengthscales|period)$")
    factors: Dict[Tuple[int, ...], Dict[str, float]] = {}
    for path, value in values.items():
        found = pattern.match(path)
        if found:
            index = tuple(int(i) for i in re.findall(r"\[(\d+)\]", found.group(1)))
            factors.setdefault(index, {})[found.group(3)] = softplus(np.asarray(value, float))
    if not factors:
        raise KeyError("kernel parameters")
    depth = max(len(index) for index in factors)
    terms: Dict[Tuple[int, ...], List[_Factor]] = {}
    for index in sorted(factors):
        if len(index) != depth:
            raise KeyError(f"kernel layout {sorted(factors)}")
        parts = factors[index]
        factor = _Factor(float(parts["variance"]), parts["lengthscales"],
                         float(parts["period"]) if "period" in parts else 0.0)
        terms.setdefault(index[:-1] if depth == 2 else (), []).append(factor)
    return [terms[key] for key in sorted(terms)]
