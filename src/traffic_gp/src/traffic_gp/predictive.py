"""Predictive distributions of people counts, in NumPy (no TensorFlow).

The model gives a Gaussian over the log density f at each place and time; a count watched with
exposure e is then Poisson(e * exp(f)) mixed over f. Everything here integrates f out by
Gauss-Hermite quadrature. A point forecast (a baseline's rate) is the case var = 0.
"""
import numpy as np
from scipy import special, stats

NODES, WEIGHTS = np.polynomial.hermite.hermgauss(24)
LOG_WEIGHTS = np.log(WEIGHTS / np.sqrt(np.pi))
CHUNK = 20000


def expected_value(mean, var):
    """E[exp(f)] for f ~ N(mean, var): the expected density."""
    return np.exp(np.asarray(mean) + np.asarray(var) / 2.0)


def expected_std(mean, var):
    """Standard deviation of exp(f): the uncertainty of the expected density."""
    mean, var = np.asarray(mean), np.asarray(var)
    return np.sqrt(np.expm1(var) * np.exp(2.0 * mean + var))


def _rates(mean, var, expo):
    mean, var, expo = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float),
                                          np.asarray(expo, float))
    f = mean[..., None] + np.sqrt(2.0 * np.maximum(var, 0.0))[..., None] * NODES
    return expo[..., None] * np.exp(f)


def log_density(count, mean, var, expo):
    """log p(count) of the mixture, per row (held-out log-likelihood)."""
    rates = _rates(mean, var, expo)
    count = np.asarray(count, float)[..., None]
    log_p = count * np.log(np.maximum(rates, 1e-300)) - rates - special.gammaln(count + 1.0)
    return special.logsumexp(log_p + LOG_WEIGHTS, axis=-1)


def cdf(count, mean, var, expo):
    """P(N <= count) of the mixture, per row (count may be -1: gives 0)."""
    rates = _rates(mean, var, expo)
    return np.sum(stats.poisson.cdf(np.asarray(count, float)[..., None], rates) * WEIGHTS, -1) \
        / np.sqrt(np.pi)


def quantile(q: float, mean, var, expo):
    """Smallest count k with P(N <= k) >= q, per row."""
    mean, var, expo = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float),
                                          np.asarray(expo, float))
    out = np.zeros(mean.shape)
    flat_out = out.reshape(-1)
    flat = [a.reshape(-1) for a in (mean, var, expo)]
    for start in range(0, flat_out.size, CHUNK):
        part = slice(start, start + CHUNK)
        rates = _rates(flat[0][part], flat[1][part], flat[2][part])
        k = np.zeros(rates.shape[0])
        todo = np.ones(rates.shape[0], bool)
        while todo.any():
            below = np.sum(stats.poisson.cdf(k[todo, None], rates[todo]) * WEIGHTS, -1) \
                / np.sqrt(np.pi) < q - 1e-12
            rows = np.nonzero(todo)[0]
            k[rows[below]] += 1
            todo[rows[~below]] = False
        flat_out[part] = k
    return out


def interval(level: float, mean, var, expo):
    """Central predictive interval (lower, upper) of the count holding `level` of the mass."""
    tail = (1.0 - level) / 2.0
    return quantile(tail, mean, var, expo), quantile(1.0 - tail, mean, var, expo)


def randomized_pit(count, mean, var, expo, rng: np.random.Generator):
    """Randomised probability integral transform (Czado, Gneiting & Held 2009): uniform on (0, 1)
    for a calibrated forecast of discrete counts."""
    count = np.asarray(count, float)
    lower = cdf(count - 1.0, mean, var, expo)
    upper = cdf(count, mean, var, expo)
    return lower + rng.random(count.shape) * (upper - lower)


def coverage(count, mean, var, expo, level: float = 0.9, rng=None):
    """Share of counts inside the central `level` interval, two ways: `inside` counts a held-out
    count inside [lower, upper] (conservative for small counts: even the true distribution covers
    more than `level`), `pit` uses the randomised PIT (a calibrated forecast gives `level`)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    lower, upper = interval(level, mean, var, expo)
    count = np.asarray(count, float)
    pit = randomized_pit(count, mean, var, expo, rng)
    tail = (1.0 - level) / 2.0
    return {"inside": float(np.mean((count >= lower) & (count <= upper))),
            "pit": float(np.mean((pit >= tail) & (pit <= 1.0 - tail)))}
