"""GPflow pieces of the crowd model: the count likelihoods with exposure (Poisson, and negative
binomial for overdispersed counts), the space-time kernel, the SVGP itself, its training step and
its parameters as plain arrays.

Importing this module is cheap: TensorFlow and GPflow are imported (through `traffic_gp._tf`) by
the first function called here, so the estimator can import it at the top while a process that
only predicts from a saved posterior (`posterior.PosteriorSnapshot`) never loads TensorFlow.
"""
from typing import Dict, Tuple

import numpy as np

from traffic_gp._tf import libs
from traffic_gp.errors import ModelFormatError

FLOAT = np.float64
GAUSS_HERMITE = np.polynomial.hermite.hermgauss(20)
_LIKELIHOOD = {}      # likelihood classes by name, made once TensorFlow is imported
LIKELIHOODS = ("negbin", "poisson")
INITIAL_DISPERSION = 10.0


def library_versions() -> str:
    """'tensorflow X, gpflow Y' (imports them)."""
    return libs().versions


def poisson_exposure():
    """A new PoissonExposure likelihood (the class is built on first use: it derives from GPflow's
    Likelihood)."""
    if "poisson" not in _LIKELIHOOD:
        _LIKELIHOOD["poisson"] = _poisson_exposure_class(libs())
    return _LIKELIHOOD["poisson"]()


def negbin_exposure(dispersion: float = INITIAL_DISPERSION):
    """A new NegBinExposure likelihood with a trainable dispersion (built on first use)."""
    if "negbin" not in _LIKELIHOOD:
        _LIKELIHOOD["negbin"] = _negbin_exposure_class(libs())
    return _LIKELIHOOD["negbin"](dispersion)


def make_likelihood(name: str):
    if name == "poisson":
        return poisson_exposure()
    if name == "negbin":
        return negbin_exposure()
    raise ModelFormatError(f"unknown likelihood {name!r}; known: {', '.join(LIKELIHOODS)}")


def dispersion(model):
    """The fitted negative-binomial dispersion r (Var = mu + mu^2 / r), or None for Poisson."""
    value = getattr(model.likelihood, "dispersion", None)
    return None if value is None else float(value.numpy())


def _negbin_exposure_class(lib):
    tf, gpflow = lib.tf, lib.gpflow

    class NegBinExposure(gpflow.likelihoods.Likelihood):
        """Overdispersed counts with exposure: Y = [count, exposure]; count ~ NB(mean mu, r) with
        mu = exposure * exp(f) and Var = mu + mu^2 / r (a Poisson whose rate has a Gamma(r, r)
        factor per row: crowds come in groups, days differ). r is trained with the
        hyperparameters; r -> infinity is the Poisson likelihood. The expectations over
        f ~ N(Fmu, Fvar) are by Gauss-Hermite quadrature."""

        def __init__(self, dispersion: float):
            super().__init__(input_dim=None, latent_dim=1, observation_dim=2)
            self.dispersion = gpflow.Parameter(dispersion, transform=gpflow.utilities.positive(),
                                               dtype=FLOAT, name="dispersion")

        def _log_pmf(self, count, log_mu):
            r = self.dispersion
            log_r = tf.math.log(r)
            log_total = tf.math.reduce_logsumexp(tf.stack([log_mu, log_r * tf.ones_like(log_mu)]),
                                                 axis=0)
            return (tf.math.lgamma(count + r) - tf.math.lgamma(r) - tf.math.lgamma(count + 1.0)
                    + r * (log_r - log_total) + count * (log_mu - log_total))

        def _log_prob(self, X, F, Y):
            count, expo = Y[..., :1], Y[..., 1:]
            return tf.reduce_sum(self._log_pmf(count, tf.math.log(expo) + F), -1)

        def _quadrature(self, Fmu, Fvar, Y):
            nodes, weights = GAUSS_HERMITE
            count, expo = Y[..., :1], Y[..., 1:]
            f = Fmu + tf.sqrt(2.0 * Fvar) * nodes                       # [..., n_nodes]
            return self._log_pmf(count, tf.math.log(expo) + f), np.log(weights / np.sqrt(np.pi))

        def _variational_expectations(self, X, Fmu, Fvar, Y):
            log_p, log_w = self._quadrature(Fmu, Fvar, Y)
            return tf.reduce_sum(log_p * np.exp(log_w), axis=-1)

        def _predict_mean_and_var(self, X, Fmu, Fvar):
            # per unit exposure, as PoissonExposure does
            mean = tf.exp(Fmu + Fvar / 2.0)
            second = tf.exp(2.0 * Fmu + 2.0 * Fvar)
            return mean, mean + second * (1.0 + 1.0 / self.dispersion) - tf.square(mean)

        def _predict_log_density(self, X, Fmu, Fvar, Y):
            log_p, log_w = self._quadrature(Fmu, Fvar, Y)
            return tf.reduce_logsumexp(log_p + log_w, axis=-1)

    return NegBinExposure


def _poisson_exposure_class(lib):
    tf, gpflow = lib.tf, lib.gpflow

    class PoissonExposure(gpflow.likelihoods.Likelihood):
        """Counts with exposure: Y = [count, exposure]; count ~ Poisson(exposure * exp(f)).

        `exp(f)` is the people density (per m^2); the exposure is the effective watched area, so
        a half-seen cell or a longer watch changes the expected count, not the density.
        """

        def __init__(self):
            super().__init__(input_dim=None, latent_dim=1, observation_dim=2)

        def _log_prob(self, X, F, Y):
            count, expo = Y[..., :1], Y[..., 1:]
            log_rate = tf.math.log(expo) + F
            return tf.reduce_sum(count * log_rate - tf.exp(log_rate) - tf.math.lgamma(count + 1.0),
                                 -1)

        def _variational_expectations(self, X, Fmu, Fvar, Y):
            count, expo = Y[..., :1], Y[..., 1:]
            return tf.reduce_sum(count * (tf.math.log(expo) + Fmu) - expo * tf.exp(Fmu + Fvar / 2.0)
                                 - tf.math.lgamma(count + 1.0), -1)

        def _predict_mean_and_var(self, X, Fmu, Fvar):
            # Y's second column (the exposure) is not known here: per unit exposure.
            mean = tf.exp(Fmu + Fvar / 2.0)
            return mean, mean + (tf.exp(Fvar) - 1.0) * tf.square(mean)

        def _predict_log_density(self, X, Fmu, Fvar, Y):
            nodes, weights = GAUSS_HERMITE
            count, expo = Y[..., :1], Y[..., 1:]
            f = Fmu + tf.sqrt(2.0 * Fvar) * nodes                       # [..., n_nodes]
            log_rate = tf.math.log(expo) + f
            log_p = count * log_rate - tf.exp(log_rate) - tf.math.lgamma(count + 1.0)
            return tf.reduce_logsumexp(log_p + np.log(weights / np.sqrt(np.pi)), axis=-1)

    return PoissonExposure


def _space(lengthscale: float, spatial_dims: int = 2):
    """Squared exponential over the first `spatial_dims` input columns: one lengthscale per
    column for map coordinates (x, y), one shared lengthscale for more columns (a geodesic
    embedding's coordinates are all metres of walking distance)."""
    gpflow = libs().gpflow
    lengthscales = [lengthscale, lengthscale] if spatial_dims == 2 else lengthscale
    return gpflow.kernels.SquaredExponential(lengthscales=lengthscales,
                                             active_dims=list(range(spatial_dims)))


def _cycle(period: float, lengthscale: float, variance: float = 1.0, column: int = 2):
    gpflow = libs().gpflow
    base = gpflow.kernels.SquaredExponential(variance=variance, lengthscales=lengthscale,
                                             active_dims=[column])
    kernel = gpflow.kernels.Periodic(base, period=period)
    gpflow.set_trainable(kernel.period, False)
    gpflow.set_trainable(base.variance, False)
    return kernel


def build_kernel(*, spatial_lengthscale: float, hourly: bool, weekly: bool,
                 spatial_dims: int = 2):
    """space x daily cycle [+ space x hourly cycle x daily (weekly) envelope]
    [+ space x weekly cycle]; inputs: `spatial_dims` space columns, then the time.

    Periodic lengthscales are in units of the sine of the phase: 0.5 of a 24 h period is about
    4 h, 0.3 of a 1 h period about 6 minutes (the rush before the hour).
    """
    gpflow = libs().gpflow
    k = spatial_dims
    parts = [_space(spatial_lengthscale, k) * _cycle(24.0, 0.6, column=k)]
    if hourly:   # rushes: an hourly cycle whose strength varies over the day (or week)
        envelope = _cycle(168.0, 0.1, column=k) if weekly else _cycle(24.0, 0.6, column=k)
        parts.append(_space(spatial_lengthscale, k) * _cycle(1.0, 0.3, column=k) * envelope)
    if weekly:
        parts.append(_space(spatial_lengthscale * 2, k) * _cycle(168.0, 0.5, column=k))
    return parts[0] if len(parts) == 1 else gpflow.kernels.Sum(parts)


def build_model(inducing: np.ndarray, *, spatial_lengthscale: float, hourly: bool, weekly: bool,
                log_mean: float, num_data: int, train_inducing: bool, likelihood: str = "poisson"):
    """The whitened SVGP with the `likelihood` ("poisson" or "negbin", both with exposure) and a
    constant mean `log_mean`; the inputs' last column is the time, the others are space."""
    lib = libs()
    tf, gpflow = lib.tf, lib.gpflow
    kernel = build_kernel(spatial_lengthscale=spatial_lengthscale, hourly=hourly, weekly=weekly,
                          spatial_dims=inducing.shape[1] - 1)
    model = gpflow.models.SVGP(kernel, make_likelihood(likelihood),
                               gpflow.inducing_variables.InducingPoints(inducing.astype(FLOAT)),
                               mean_function=gpflow.mean_functions.Constant(np.array([log_mean])),
                               num_latent_gps=1, whiten=True)
    # A variable, so that online updates can grow the data set without retracing the step.
    model.num_data = tf.Variable(float(num_data), dtype=FLOAT, trainable=False, name="num_data")
    gpflow.set_trainable(model.inducing_variable.Z, train_inducing)
    return model


class Trainer:
    """One compiled step: natural gradients for q(u), Adam for the hyperparameters, from a single
    forward and backward pass (GPflow's two `minimize` calls would need two). `compiled=False`
    runs the same step eagerly: for a few dozen steps that is quicker than tracing it."""

    def __init__(self, model, *, learning_rate: float, gamma: float, compiled: bool = True):
        lib = libs()
        tf, gpflow = lib.tf, lib.gpflow
        self._tf = tf
        self.model, self.compiled = model, compiled
        gpflow.set_trainable(model.q_mu, False)
        gpflow.set_trainable(model.q_sqrt, False)
        self.gamma = tf.Variable(gamma, dtype=FLOAT, trainable=False)
        self.natgrad = gpflow.optimizers.NaturalGradient(gamma=self.gamma)
        self.adam = lib.Adam(learning_rate=learning_rate)
        columns = int(model.inducing_variable.Z.shape[1])
        spec = [tf.TensorSpec([None, columns], FLOAT), tf.TensorSpec([None, 2], FLOAT)]
        single_pass = hasattr(self.natgrad, "_natgrad_apply_gradients")  # GPflow 2.9 - 2.11
        step = self._step if single_pass else self._two_pass_step
        functions = (step, lambda X, Y: model.elbo((X, Y)),
                     lambda X, Y: model.predict_log_density((X, Y)))
        if compiled:   # GPflow's code has no tensor-dependent Python control flow: traced as
            # written, without AutoGraph's source conversion (half of the tracing CPU, the same graph)
            functions = [tf.function(f, input_signature=spec, autograph=False) for f in functions]
        else:       # eager: the arrays become tensors of the same types as the signature's
            functions = [_as_tensors(tf, f) for f in functions]
        self.step, self.elbo, self.log_density = functions

    def trace(self) -> None:
        """Trace the compiled functions now (seconds of CPU; nothing is trained), so that the
        first training step after this does not pay for it."""
        if self.compiled:
            for function in (self.step, self.elbo, self.log_density):
                function.get_concrete_function()

    def _step(self, X, Y):
        model = self.model
        tf = self._tf
        q_vars = [model.q_mu.unconstrained_variable, model.q_sqrt.unconstrained_variable]
        hypers = list(model.trainable_variables)
        with tf.GradientTape(watch_accessed_variables=False) as tape:
            tape.watch(q_vars + hypers)
            loss = model.training_loss((X, Y))
        grads = tape.gradient(loss, q_vars + hypers)
        self.natgrad._natgrad_apply_gradients(grads[0], grads[1], model.q_mu, model.q_sqrt)
        self.adam.apply_gradients(zip(grads[2:], hypers))

    def _two_pass_step(self, X, Y):
        loss = self.model.training_loss_closure((X, Y), compile=False)
        self.natgrad.minimize(loss, [(self.model.q_mu, self.model.q_sqrt)])
        self.adam.minimize(loss, self.model.trainable_variables)


def _as_tensors(tf, function):
    def call(X, Y):
        return function(tf.constant(X, dtype=FLOAT), tf.constant(Y, dtype=FLOAT))
    return call


def predict_latent(model, X: np.ndarray, full_cov: bool = False,
                   chunk: int = 20000) -> Tuple[np.ndarray, np.ndarray]:
    """Mean and (co)variance of f at the rows of X, in chunks of rows (memory stays small)."""
    tf = libs().tf
    if full_cov:
        mean, cov = model.predict_f(tf.constant(X, dtype=FLOAT), full_cov=True)
        return mean.numpy()[:, 0], cov.numpy()[0]
    means, variances = [], []
    for start in range(0, max(len(X), 1), chunk):
        mean, var = model.predict_f(tf.constant(X[start:start + chunk], dtype=FLOAT))
        means.append(mean.numpy()[:, 0])
        variances.append(var.numpy()[:, 0])
    return np.concatenate(means), np.concatenate(variances)


def parameter_values(model) -> Dict[str, np.ndarray]:
    """Every parameter in its unconstrained form (restores bit for bit), and plain variables."""
    gpflow = libs().gpflow
    values = {}
    for path, variable in gpflow.utilities.parameter_dict(model).items():
        if isinstance(variable, gpflow.Parameter):
            values[path] = variable.unconstrained_variable.numpy()
        else:
            values[path] = variable.numpy()
    return values


def assign_parameter_values(model, values: Dict[str, np.ndarray]) -> None:
    """Set every parameter from `parameter_values`' form; refuses another layout or shape."""
    gpflow = libs().gpflow
    params = gpflow.utilities.parameter_dict(model)
    if set(params) != set(values):
        missing, extra = sorted(set(params) - set(values)), sorted(set(values) - set(params))
        raise ModelFormatError(f"saved parameters do not fit the model: missing {missing[:3]}, "
                               f"unexpected {extra[:3]}")
    for path, variable in params.items():
        target = variable.unconstrained_variable if isinstance(variable, gpflow.Parameter) \
            else variable
        if tuple(target.shape) != tuple(np.shape(values[path])):
            raise ModelFormatError(f"saved {path} has shape {np.shape(values[path])}, "
                                   f"the model needs {tuple(target.shape)}")
        target.assign(values[path])


def assign_hyperparameters(model, values: Dict[str, np.ndarray]) -> int:
    """Warm start: set the kernel's and the likelihood's parameters (not q(u), the inducing
    points or the mean) from `parameter_values` of a model of the same settings, where the
    shapes agree; returns how many were set."""
    gpflow = libs().gpflow
    done = 0
    for path, variable in gpflow.utilities.parameter_dict(model).items():
        if not path.startswith((".kernel", ".likelihood")) or path not in values:
            continue
        target = variable.unconstrained_variable if isinstance(variable, gpflow.Parameter) \
            else variable
        if tuple(target.shape) == tuple(np.shape(values[path])):
            target.assign(values[path])
            done += 1
    return done
