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


def test_days_with_enough_counts_are_numbered_and_small_days_join_the_day_before():
    from traffic_gp.calibration import day_index
    # days 0 and 1 have two counts each, days 2 and 3 one each: they join day 1
    t = [1.0, 2.0, 25.0, 26.0, 49.0, 73.0]
    np.testing.assert_array_equal(day_index(t, min_days=2, min_rows=2), [0, 0, 1, 1, 1, 1])
    assert day_index(t, min_days=3, min_rows=2) is None        # two such days: pooled


def test_the_median_days_coverage_is_used_not_the_pooled_one():
    from traffic_gp.calibration import _shares
    # a count is inside (and its PIT in the band) when F = [0.2, 0.3]; outside when [0.96, 0.99]
    ins, out = (0.2, 0.3), (0.96, 0.99)
    # day 0: 8 of 8 inside; day 1: 2 of 4; day 2: 3 of 4 -> per day 1, 0.5, 0.75
    rows = [ins] * 8 + [ins, ins, out, out] + [ins, ins, ins, out]
    days = np.array([0] * 8 + [1] * 4 + [2] * 4)
    lower, upper = (np.array(v) for v in zip(*rows))
    assert _shares(lower, upper) == pytest.approx((13 / 16, 13 / 16))      # pooled
    assert _shares(lower, upper, days=days) == pytest.approx((0.75, 0.75))  # median day


def test_unusual_calibration_days_do_not_widen_the_intervals_of_ordinary_days():
    """Seven held-out days of which two (an event) scatter the counts far beyond the forecast,
    then fourteen ordinary days: pooled calibration widens for the event days and covers
    about 98% of the ordinary days; the median day's calibration stays within 85-95%."""
    rng = np.random.default_rng(3)

    def days(n_days, unusual, per_day=300, r=5.0):
        t = np.repeat(np.arange(n_days) * 24.0 + 10.0, per_day)
        rate = rng.uniform(2.0, 40.0, t.size)
        event = np.isin(np.floor(t / 24.0), unusual)
        shift = np.where(event, rng.normal(0.0, 1.0, t.size), 0.0)
        return t, rng.negative_binomial(r, r / (r + rate * np.exp(shift))), np.log(rate)

    t, count, mean = days(7, [4, 5])
    _, fresh, fresh_mean = days(14, [])

    def covered(cal):
        m, v = widen(fresh_mean, 0.0, cal.latent_variance)
        low, high = predictive.interval(0.9, m, v, 1.0, cal.dispersion)
        return np.mean((fresh >= low) & (fresh <= high))

    assert covered(calibrate(count, mean, 0.0, 1.0)) > 0.95            # pooled: too wide
    assert 0.85 <= covered(calibrate(count, mean, 0.0, 1.0, t=t)) <= 0.95
