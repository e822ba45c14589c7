"""Predictive count distributions (Poisson mixed over a log-normal rate)."""
import numpy as np
import pytest
from scipy import stats

from traffic_gp import predictive


def test_without_rate_uncertainty_it_is_the_poisson_distribution():
    counts = np.array([0, 1, 3, 7])
    rate = np.array([0.2, 1.0, 2.5, 4.0])
    np.testing.assert_allclose(predictive.log_density(counts, np.log(rate), 0.0, 1.0),
                               stats.poisson.logpmf(counts, rate), rtol=1e-9)
    for q in (0.05, 0.5, 0.95):
        np.testing.assert_array_equal(predictive.quantile(q, np.log(rate), 0.0, 1.0),
                                      stats.poisson.ppf(q, rate))


def test_mixture_matches_sampling():
    rng = np.random.default_rng(0)
    mean, var, expo = -0.5, 0.6, 2.0
    samples = rng.poisson(expo * np.exp(rng.normal(mean, np.sqrt(var), 400000)))
    for k in (0, 1, 4):
        assert predictive.cdf(k, mean, var, expo) == pytest.approx(np.mean(samples <= k), abs=3e-3)
    assert predictive.expected_value(mean, var) * expo == pytest.approx(samples.mean(), rel=0.01)
    low, high = predictive.interval(0.9, mean, var, expo)
    assert (low, high) == (np.quantile(samples, 0.05, method="inverted_cdf"),
                           np.quantile(samples, 0.95, method="inverted_cdf"))


def test_randomised_pit_coverage_of_a_calibrated_forecast_is_the_level():
    rng = np.random.default_rng(1)
    rate = rng.uniform(0.05, 3.0, 20000)
    counts = rng.poisson(rate)
    cover = predictive.coverage(counts, np.log(rate), 0.0, 1.0, 0.9, rng)
    assert cover["pit"] == pytest.approx(0.9, abs=0.01)
    assert cover["inside"] >= 0.9                       # discrete intervals over-cover
    too_narrow = predictive.coverage(counts, np.log(rate * 0.4), 0.0, 1.0, 0.9, rng)
    assert too_narrow["pit"] < 0.8
