"""Predictive distributions of people counts, in NumPy (no TensorFlow).

The model gives a Gaussian over the log density f at each place and time; a count watched with
exposure e is then Poisson(e * exp(f)) (`dispersion=None`) or negative binomial with mean
mu = e * exp(f) and variance mu + mu^2 / r (`dispersion=r`, overdispersed counts), mixed over f.
Everything here integrates f out by Gauss-Hermite quadrature. A point forecast (a baseline's
rate) is the case var = 0.
"""
from typing import Optional

import numpy as np
from scipy import special, stats

NODES, WEIGHTS = np.polynomial.hermite.hermgauss(24)
LOG_WEIGHTS = np.log(WEIGHTS / np.sqrt(np.pi))
POINT = (np.zeros(1), np.full(1, np.sqrt(np.pi)))    # one node: a point forecast (var = 0)
CHUNK = 20000


def expected_value(mean, var):
    """E[exp(f)] for f ~ N(mean, var): the expected density."""
    return np.exp(np.asarray(mean) + np.asarray(var) / 2.0)


def expected_std(mean, var):
    """Standard deviation of exp(f): the uncertainty of the expected density."""
    mean, var = np.asarray(mean), np.asarray(var)
    return np.sqrt(np.expm1(var) * np.exp(2.0 * mean + var))


def _quadrature(var):
    """Gauss-Hermite nodes and weights: one node where every variance is 0 (point forecasts,
    e.g. a baseline's rate: all nodes would be equal)."""
    return POINT if not np.any(np.asarray(var)) else (NODES, WEIGHTS)


def _rates(mean, var, expo):
    mean, var, expo = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float),
                                          np.asarray(expo, float))
    nodes = _quadrature(var)[0]
    f = mean[..., None] + np.sqrt(2.0 * np.maximum(var, 0.0))[..., None] * nodes
    return expo[..., None] * np.exp(f)


def _component_cdf(k, rates, dispersion: Optional[float]):
    if dispersion is None:
        return stats.poisson.cdf(k, rates)
    return stats.nbinom.cdf(k, dispersion, dispersion / (dispersion + rates))


def _component_ppf(q, rates, dispersion: Optional[float]):
    if dispersion is None:
        return stats.poisson.ppf(q, rates)
    return stats.nbinom.ppf(q, dispersion, dispersion / (dispersion + rates))


def log_density(count, mean, var, expo, dispersion: Optional[float] = None):
    """log p(count) of the mixture, per row (held-out log-likelihood)."""
    rates = np.maximum(_rates(mean, var, expo), 1e-300)
    count = np.asarray(count, float)[..., None]
    if dispersion is None:
        log_p = count * np.log(rates) - rates - special.gammaln(count + 1.0)
    else:
        r = float(dispersion)
        log_total = np.logaddexp(np.log(rates), np.log(r))
        log_p = (special.gammaln(count + r) - special.gammaln(r) - special.gammaln(count + 1.0)
                 + r * (np.log(r) - log_total) + count * (np.log(rates) - log_total))
    return special.logsumexp(log_p + np.log(_quadrature(var)[1] / np.sqrt(np.pi)), axis=-1)


def cdf(count, mean, var, expo, dispersion: Optional[float] = None):
    """P(N <= count) of the mixture, per row (count may be -1: gives 0)."""
    rates = _rates(mean, var, expo)
    return np.sum(_component_cdf(np.asarray(count, float)[..., None], rates, dispersion)
                  * _quadrature(var)[1], -1) / np.sqrt(np.pi)


def quantile(q: float, mean, var, expo, dispersion: Optional[float] = None):
    """Smallest count k with P(N <= k) >= q, per row (bisection between the quadrature
    components' own quantiles, which bracket the mixture's)."""
    mean, var, expo = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float),
                                          np.asarray(expo, float))
    out = np.zeros(mean.shape)
    flat_out = out.reshape(-1)
    flat = [a.reshape(-1) for a in (mean, var, expo)]
    for start in range(0, flat_out.size, CHUNK):
        part = slice(start, start + CHUNK)
        rates = _rates(flat[0][part], flat[1][part], flat[2][part])
        weights = _quadrature(flat[1][part])[1]
        ppf = _component_ppf(q, rates, dispersion)
        low = np.min(ppf, axis=1) - 1.0           # P(N <= low) < q
        high = np.max(ppf, axis=1)                # P(N <= high) >= q
        while np.any(high - low > 1):
            mid = np.floor((low + high) / 2.0)
            ok = np.sum(_component_cdf(mid[:, None], rates, dispersion) * weights, -1) \
                / np.sqrt(np.pi) >= q - 1e-12
            high = np.where(ok, mid, high)
            low = np.where(ok, low, mid)
        flat_out[part] = np.maximum(high, 0.0)
    return out


def interval(level: float, mean, var, expo, dispersion: Optional[float] = None):
    """Central predictive interval (lower, upper) of the count holding `level` of the mass."""
    tail = (1.0 - level) / 2.0
    return (quantile(tail, mean, var, expo, dispersion),
            quantile(1.0 - tail, mean, var, expo, dispersion))


def randomized_pit(count, mean, var, expo, rng: np.random.Generator,
                   dispersion: Optional[float] = None):
    """Randomised probability integral transform (Czado, Gneiting & Held 2009): uniform on (0, 1)
    for a calibrated forecast of discrete counts."""
    count = np.asarray(count, float)
    lower = cdf(count - 1.0, mean, var, expo, dispersion)
    upper = cdf(count, mean, var, expo, dispersion)
    return lower + rng.random(count.shape) * (upper - lower)


def coverage(count, mean, var, expo, level: float = 0.9, rng=None,
             dispersion: Optional[float] = None):
    """Share of counts inside the central `level` interval, two ways: `inside` counts a held-out
    count inside [lower, upper] (conservative for small counts: even the true distribution covers
    more than `level`), `pit` uses the randomised PIT (a calibrated forecast gives `level`)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    lower, upper = interval(level, mean, var, expo, dispersion)
    count = np.asarray(count, float)
    pit = randomized_pit(count, mean, var, expo, rng, dispersion)
    tail = (1.0 - level) / 2.0
    return {"inside": float(np.mean((count >= lower) & (count <= upper))),
            "pit": float(np.mean((pit >= tail) & (pit <= 1.0 - tail)))}
