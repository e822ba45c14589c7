"""The rolling level with its uncertainty (traffic_gp.level), NumPy only.

Data come from a known process: a weekly pattern per place (the forecast is that true pattern,
not an output of the code under test), a weekly level that moves as a random walk in log space
(sd 0.4 a week) with a collapse to a fifth in one week, and negative-binomial counts around it
(a Poisson count whose rate has a Gamma(r, r) factor, r = 10). The 0.9 level, r and the walk's
variance are those of the generating process."""
import numpy as np
import pytest
from scipy import special

from traffic_gp import level, predictive

TRUE_R, WALK_SD, SHIFT_WEEK, N_WEEKS, N_PLACES = 10.0, 0.4, 12, 30, 8


def pattern(place, hour_of_week):
    hour = np.mod(hour_of_week, 24)
    weekend = (hour_of_week // 24) >= 5
    return (40.0 + 10.0 * place) * (1.0 + np.exp(-0.5 * ((hour - 13.0) / 3.0) ** 2)) \
        * np.where(weekend, 0.5, 1.0)


def process(seed=0):
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, WALK_SD, (N_PLACES, N_WEEKS))
    steps[:, SHIFT_WEEK] += np.log(0.2)
    log_level = np.cumsum(steps, axis=1)
    hours = np.arange(N_WEEKS * 168)
    key = np.repeat(np.arange(N_PLACES), hours.size)
    abs_hour = np.tile(hours, N_PLACES)
    forecast = pattern(key, abs_hour % 168)
    rate = forecast * np.exp(log_level[key, abs_hour // 168])
    count = rng.poisson(rate * rng.gamma(TRUE_R, 1.0 / TRUE_R, rate.size)).astype(float)
    return {"key": key, "abs_hour": abs_hour, "count": count}, forecast


def weeks(rows, forecast, first, last):
    keep = (rows["abs_hour"] >= first * 168) & (rows["abs_hour"] < last * 168)
    return {k: v[keep] for k, v in rows.items()}, forecast[keep]


def test_factors_are_last_weeks_counts_over_forecast_clipped():
    history = {"key": np.array([0, 0, 1, 1, 3]), "abs_hour": np.array([0, 5, 1, 2, 3]),
               "count": np.array([10.0, 30.0, 5.0, 5.0, 1000.0])}
    forecast = np.array([20.0, 20.0, 10.0, 10.0, 1.0])
    rows = {"key": np.array([0, 1, 2, 3, 0]), "abs_hour": np.array([170, 200, 180, 169, 400])}
    factors = level.level_factors(history, forecast, rows, origin_hour=168)
    # key 0: 40 / 40; key 1: 10 / 20; key 2: no counts; key 3: 1000 clipped to 5; the last row's
    # week (2) looks at week 1, which has no history
    np.testing.assert_allclose(factors, [1.0, 0.5, 1.0, 5.0, 1.0])


def test_level_latent_keeps_the_expected_value_and_adds_the_variance():
    mean, var = level.level_latent(np.log(50.0), 0.2, 2.0, 0.3)
    assert predictive.expected_value(mean, var) == pytest.approx(
        predictive.expected_value(np.log(50.0), 0.2) * 2.0)
    assert var == pytest.approx(0.5)


@pytest.fixture(scope="module")
def calibrated():
    rows, forecast = process()
    origin = 2
    cal_rows, cal_forecast = weeks(rows, forecast, origin, 10)
    cal_factor = level.level_factors(rows, forecast, cal_rows, origin * 168)
    cal = level.calibrate(cal_rows["count"], np.log(cal_forecast), 0.0, cal_factor)
    # test: the weeks after the collapse has been seen (its own week cannot be forecast)
    test_rows, test_forecast = weeks(rows, forecast, SHIFT_WEEK + 1, N_WEEKS)
    test_factor = level.level_factors(rows, forecast, test_rows, (SHIFT_WEEK + 1) * 168)
    return cal, test_rows, np.log(test_forecast), test_factor


def test_calibration_finds_the_processes_spread_of_the_rate(calibrated):
    cal = calibrated[0]
    # Per count, the level's log-normal factor and the Gamma factor of the negative binomial
    # are nearly interchangeable, but their sum is not: the log rate of a count varies around
    # last week's level by the walk (variance 0.16; last week's estimate is nearly exact, from
    # thousands of counts) plus the log of a Gamma(r, r) factor (variance trigamma(r)).
    truth = WALK_SD ** 2 + special.polygamma(1, TRUE_R)
    found = cal["level_var"] + special.polygamma(1, cal["dispersion"])
    assert found == pytest.approx(truth, abs=0.06)
    assert cal["level_var"] >= 0.07


def test_intervals_with_the_level_variance_cover_after_a_level_shift(calibrated):
    cal, test_rows, log_forecast, factor = calibrated
    rng = np.random.default_rng(1)
    m, v = level.level_latent(log_forecast, 0.0, factor, cal["level_var"])
    cover = predictive.coverage(test_rows["count"], m, v, 1.0, 0.9, rng, cal["dispersion"])
    assert 0.85 <= cover["pit"] <= 0.95
    assert 0.85 <= cover["inside"] <= 0.96
    # without the level's variance the same intervals miss far more than 10 %
    m0, v0 = level.level_latent(log_forecast, 0.0, factor, 0.0)
    assert predictive.coverage(test_rows["count"], m0, v0, 1.0, 0.9, rng,
                               cal["dispersion"])["pit"] < 0.8


def test_online_level_variance_is_the_mean_square_of_recent_level_changes():
    # key 0: weekly levels 1, e^0.3, e^-0.1 in weeks 0, 1, 2 (changes 0.3, -0.4); key 1: only
    # week 2 (no change seen)
    levels = {(0, 0): 1.0, (0, 1): np.exp(0.3), (0, 2): np.exp(-0.1), (1, 2): 2.0}
    history = {"key": [], "abs_hour": [], "count": []}
    for (key, week), value in levels.items():
        history["key"] += [key, key]
        history["abs_hour"] += [week * 168 + 3, week * 168 + 50]
        history["count"] += [40.0 * value, 60.0 * value]
    history = {k: np.array(v) for k, v in history.items()}
    forecast = np.array([40.0, 60.0] * len(levels))
    rows = {"key": np.array([0, 1, 0, 0]), "abs_hour": np.array([3 * 168, 3 * 168 + 1,
                                                                 2 * 168, 9 * 168])}
    s = level.rolling_level_variance(history, forecast, rows, 0, floor=0.01, window=4)
    # week 3 sees both changes; week 2 only the first; week 9's window (weeks 5-8) none
    np.testing.assert_allclose(s, [(0.09 + 0.16) / 2, (0.09 + 0.16) / 2, 0.09, 0.01])
    high = level.rolling_level_variance(history, forecast, rows, 0, floor=0.2, window=4)
    np.testing.assert_allclose(high, [0.2, 0.2, 0.2, 0.2])
