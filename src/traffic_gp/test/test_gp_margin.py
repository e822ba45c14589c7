"""The GP is served only when it forecasts the held-out days clearly better than the best
tuned baseline (GP_MARGIN); else the baselines are served and the status says so."""
import numpy as np
import pytest

from traffic_gp import serving
from traffic_gp.observations import Observations
from traffic_gp.places import PlaceIndex


def test_the_ratio_is_the_better_of_gp_and_blend_over_the_best_baseline():
    assert serving.gp_ratio({"gp": 9.0, "blend": 8.0, "fremen": 10.0,
                             "binned_mean": 12.0}) == pytest.approx(0.8)
    assert serving.gp_ratio({"gp": 9.5, "fremen": 11.0, "binned_mean": 10.0}) \
        == pytest.approx(0.95)
    assert serving.gp_ratio({"gp": 9.5}) is None


def test_the_count_noise_is_taken_out_of_both_squared_errors():
    # squared errors 0.125 and 0.145 with noise 0.1: excess 0.025 and 0.045 -> sqrt(5/9)
    rmse = {"gp": np.sqrt(0.125), "fremen": np.sqrt(0.145), "binned_mean": 1.0}
    assert serving.gp_ratio(rmse, 0.1) == pytest.approx(np.sqrt(0.025 / 0.045))
    # the GP at the noise: 1% of its squared error kept, 0.01 x 0.09 / (0.145 - 0.1) = 0.02
    rmse["gp"] = 0.3
    assert serving.gp_ratio(rmse, 0.1) == pytest.approx(np.sqrt(0.0009 / 0.045))


def hourly_places(days: int, seed: int):
    """Hourly counts at 6 places 1 m apart with a fixed rate per place and hour of the day."""
    table = np.exp(np.random.default_rng(7).normal(2.0, 0.8, (6, 24)))
    t = np.tile(np.arange(days * 24) + 0.5, 6)
    place = np.repeat(np.arange(6), days * 24)
    rate = table[place, np.floor(np.mod(t, 24)).astype(int)]
    count = np.random.default_rng(seed).poisson(rate)
    return Observations(place.astype(float), np.zeros(t.size), t, np.ones(t.size), count), rate


def build(gp_rate_noise: float):
    """`serving.build` with a GP forecast of the true rates scattered by `gp_rate_noise`."""
    rows, rate = hourly_places(4, 0)         # two days to fit the tables on, two held out
    held_rows = np.nonzero(rows.t >= 2 * 24)[0]
    fit_rows = np.nonzero(rows.t < 2 * 24)[0]
    held = rows.subset(held_rows)
    noise = np.random.default_rng(1).normal(0.0, gp_rate_noise, held_rows.size)
    return serving.build(np.log(rate[held_rows]) + noise, np.zeros(held_rows.size),
                         PlaceIndex().fit(rows.x, rows.y), rows.subset(fit_rows), held,
                         fit_days=2, shortest_period=1.0)


def test_a_gp_forecasting_the_true_rates_is_served():
    served = build(0.0)
    assert served.report["gp_ratio"] < serving.GP_MARGIN, served.report
    assert not served.report["gp_lost"] and served.verdict() == ""
    assert served.report["default"] in ("gp", "blend")


def test_a_gp_no_better_than_the_baselines_is_not_served_and_the_status_says_so():
    served = build(0.5)        # the rates scattered by a factor of e^0.5: worse than the tables
    report = served.report
    assert report["gp_ratio"] > serving.GP_MARGIN and report["gp_lost"], report
    assert report["default"] in serving.BASELINES
    assert report["served_places"]["gp"] == 0 and report["served_places"]["blend"] == 0
    assert served.summary().startswith(
        f"GP {report['gp_ratio']:.2f}x the best baseline on the held-out days (needs <= 0.9x): "
        "serving the baselines; serving " + report["default"])
