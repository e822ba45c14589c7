"""Interval widths calibrated on held-out counts (NumPy only): overdispersed counts get intervals
that hold about 90% of fresh counts where Poisson ones hold far fewer."""
import numpy as np
import pytest

from traffic_gp import predictive
from traffic_gp.calibration import COVERAGE_BAND, calibrate, inside_share, widen


def overdispersed(rng, n, r=3.0):
    """Counts of a negative-binomial process with dispersion r around known rates."""
    rate = rng.uniform(0.5, 40.0, n)
    return rng.negative_binomial(r, r / (r + rate)), np.log(rate)


def test_inside_share_is_the_share_inside_the_quantile_interval():
    rng = np.random.default_rng(0)
    count, mean = overdispersed(rng, 2000)
    var = rng.uniform(0.0, 0.3, count.size)
    for dispersion in (None, 4.0):
        low, high = predictive.interval(0.9, mean, var, 1.0, dispersion)
        expected = np.mean((count >= low) & (count <= high))
        assert inside_share(count, mean, var, 1.0, dispersion) == pytest.approx(expected, abs=0.01)


def test_calibrated_intervals_cover_fresh_overdispersed_counts_where_poisson_ones_do_not():
    rng = np.random.default_rng(1)
    held, mean_held = overdispersed(rng, 4000)
    fresh, mean_fresh = overdispersed(rng, 4000)
    cal = calibrate(held, mean_held, 0.0, 1.0)
    assert COVERAGE_BAND[0] <= cal.coverage <= COVERAGE_BAND[1]
    assert cal.dispersion is not None or cal.latent_variance > 0
    m, v = widen(mean_fresh, 0.0, cal.latent_variance)
    low, high = predictive.interval(0.9, m, v, 1.0, cal.dispersion)
    covered = np.mean((fresh >= low) & (fresh <= high))
    assert 0.85 <= covered <= 0.95, (covered, cal)
    low, high = predictive.interval(0.9, mean_fresh, 0.0, 1.0, None)
    assert np.mean((fresh >= low) & (fresh <= high)) < 0.6        # Poisson: far too narrow


def test_widening_keeps_the_expected_count():
    m, v = widen(np.log([2.0, 30.0]), np.array([0.0, 0.2]), 0.35)
    np.testing.assert_allclose(predictive.expected_value(m, v),
                               predictive.expected_value(np.log([2.0, 30.0]), [0.0, 0.2]))


def test_poisson_counts_keep_narrow_intervals():
    rng = np.random.default_rng(2)
    rate = rng.uniform(0.5, 40.0, 4000)
    cal = calibrate(rng.poisson(rate), np.log(rate), 0.0, 1.0)
    assert cal.latent_variance <= 0.02 and (cal.dispersion is None or cal.dispersion > 50)
