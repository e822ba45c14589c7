"""Predictive distributions of people counts, in NumPy (no TensorFlow).

The model gives a Gaussian over the log density f at each place and time; a count watched with
exposure e is then Poisson(e * exp(f)) (`dispersion=None`) or negative binomial with mean
mu = e * exp(f) and variance mu + mu^2 / r (`dispersion=r`, overdispersed counts), mixed over f.
Everything here integrates f out by Gauss-Hermite quadrature. A point forecast (a baseline's
rate) is the case var = 0. `log_pmf` and `component_cdf` are the one count likelihood of the
NumPy side (`calibration` uses them with fewer nodes).
"""
import functools
from typing import Optional

import numpy as np
from scipy import special, stats

CHUNK = 20000


def expected_value(mean, var):
    """E[exp(f)] for f ~ N(mean, var): the expected density."""
    return np.exp(np.asarray(mean) + np.asarray(var) / 2.0)


def expected_std(mean, var):
    """Standard deviation of exp(f): the uncertainty of the expected density."""
    mean, var = np.asarray(mean), np.asarray(var)
    return np.sqrt(np.expm1(var) * np.exp(2.0 * mean + var))


@functools.lru_cache(maxsize=None)
def _hermite(n_nodes: int):
    nodes, weights = np.polynomial.hermite.hermgauss(n_nodes)
    return nodes, weights / np.sqrt(np.pi)


def node_rates(mean, var, expo, n_nodes: int = 24):
    """Expected counts expo * exp(f) at the Gauss-Hermite nodes over f ~ N(mean, var) (last
    axis), and the nodes' weights (summing to 1); one node where every variance is 0 (point
    forecasts, e.g. a baseline's rate: all nodes would be equal)."""
    mean, var, expo = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float),
                                          np.asarray(expo, float))
    if not np.any(var > 0):
        return (expo * np.exp(mean))[..., None], np.ones(1)
    nodes, weights = _hermite(n_nodes)
    f = mean[..., None] + np.sqrt(2.0 * np.maximum(var, 0.0))[..., None] * nodes
    return expo[..., None] * np.exp(f), weights


def log_pmf(count, rates, dispersion: Optional[float] = None):
    """log P(N = count) of Poisson(rates) or NB(mean rates, dispersion r), count broadcast over
    the last axis of `rates` (the quadrature nodes): the one count likelihood in NumPy."""
    count = np.asarray(count, float)[..., None]
    rates = np.maximum(rates, 1e-300)
    if dispersion is None:
        return count * np.log(rates) - rates - special.gammaln(count + 1.0)
    r = float(dispersion)
    log_total = np.logaddexp(np.log(rates), np.log(r))
    return (special.gammaln(count + r) - special.gammaln(r) - special.gammaln(count + 1.0)
            + r * (np.log(r) - log_total) + count * (np.log(rates) - log_total))


def component_cdf(k, rates, dispersion: Optional[float] = None):
    """P(N <= k) of Poisson(rates) or NB(mean rates, r), k integers broadcast over the last axis
    of `rates` (negative k: 0)."""
    k = np.broadcast_to(np.asarray(k, float)[..., None], rates.shape)
    out = np.zeros(rates.shape)
    ok = k >= 0
    if dispersion is None:
        out[ok] = special.gammaincc(k[ok] + 1.0, rates[ok])
    else:
        r = float(dispersion)
        out[ok] = special.betainc(r, k[ok] + 1.0, r / (r + rates[ok]))
    return out


def _component_ppf(q, rates, dispersion: Optional[float]):
    if dispersion is None:
        return stats.poisson.ppf(q, rates)
    return stats.nbinom.ppf(q, dispersion, dispersion / (dispersion + rates))


def log_density(count, mean, var, expo, dispersion: Optional[float] = None, *,
                n_nodes: int = 24):
    """log p(count) of the mixture, per row (held-out log-likelihood)."""
    rates, weights = node_rates(mean, var, expo, n_nodes)
    return special.logsumexp(log_pmf(count, rates, dispersion) + np.log(weights), axis=-1)


def cdf(count, mean, var, expo, dispersion: Optional[float] = None, *, n_nodes: int = 24):
    """P(N <= count) of the mixture, per row (count may be -1: gives 0)."""
    rates, weights = node_rates(mean, var, expo, n_nodes)
    return component_cdf(count, rates, dispersion) @ weights


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
        rates, weights = node_rates(flat[0][part], flat[1][part], flat[2][part])
        ppf = _component_ppf(q, rates, dispersion)
        low = np.min(ppf, axis=1) - 1.0           # P(N <= low) < q
        high = np.max(ppf, axis=1)                # P(N <= high) >= q
        while np.any(high - low > 1):
            mid = np.floor((low + high) / 2.0)
            ok = component_cdf(mid, rates, dispersion) @ weights >= q - 1e-12
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
