"""Never served worse than the baselines it carries, with calibrated intervals: a data set where
the binned mean must win, one where the GP must (test_model's simulated robots), and intervals on
overdispersed counts."""
import numpy as np
import pytest

from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.serving import FORECASTERS

DAYS = 12


def place_tables(days: int, seed: int, dispersion=None, pattern_seed: int = 7) -> Observations:
    """Hourly counts at 30 places 1 m apart, each with its own random rate per hour of the day
    (no smoothness over space or time: what a per-place table knows and a smooth kernel with a
    few inducing points cannot)."""
    table = np.exp(np.random.default_rng(pattern_seed).normal(1.5, 1.2, (30, 24)))
    rng = np.random.default_rng(seed)
    t = np.arange(days * 24) + 0.5
    rows = []
    for place in range(30):
        rate = table[place, np.floor(np.mod(t, 24)).astype(int)]
        count = rng.poisson(rate) if dispersion is None else rng.negative_binomial(
            dispersion, dispersion / (dispersion + rate))
        rows.append(Observations(np.full(t.size, float(place)), np.zeros(t.size), t,
                                 np.ones(t.size), count))
    return Observations.concat(rows)


def later_days(rows: Observations, first_day: int) -> Observations:
    return rows.subset(np.nonzero(rows.t >= first_day * 24)[0])


@pytest.fixture(scope="module")
def table_world():
    train = place_tables(DAYS, seed=0)
    model = TrafficGP(n_inducing=8, n_steps=100, batch_size=256, eval_every=25, hourly=False,
                      likelihood="poisson", profile="none", refit_steps=20,
                      random_state=0).fit(train)
    return model, later_days(place_tables(DAYS + 3, seed=1), DAYS)


def test_where_a_baseline_forecasts_the_held_out_days_better_it_is_served_and_said(table_world):
    model, test = table_world
    report = model.serving_.report
    assert report["default"] in ("fremen", "binned_mean"), report
    assert report["held_out_rmse"]["gp"] > 1.2 * min(report["held_out_rmse"]["fremen"],
                                                     report["held_out_rmse"]["binned_mean"])
    assert f"serving {report['default']}" in model.status()
    baseline = model.serving_.baselines[report["default"]]
    np.testing.assert_allclose(model.predict(test.x, test.y, test.t),
                               baseline.predict(test.x, test.y, test.t), rtol=1e-9)
    served = np.sqrt(np.mean((model.predict(test.x, test.y, test.t) - test.count) ** 2))
    gp_alone = model.serving_.report["held_out_rmse"]["gp"]
    assert served < 0.8 * gp_alone, (served, gp_alone)


def test_a_place_never_seen_is_forecast_by_the_gp(table_world):
    model, _ = table_world
    assert model.serving_.served_index(np.array([100.0]), np.array([5.0]))[0] == 0
    assert np.isfinite(model.predict(100.0, 5.0, 12.0)).all()


def test_where_the_gp_forecasts_better_it_is_served(fitted):
    """The shared GP on simulated robots (smooth over space, cells seen sparsely): served alone or
    as the larger part of its blend with the better baseline, at most places."""
    report = fitted.serving_.report
    rmse = report["held_out_rmse"]
    assert rmse["gp"] < min(rmse["fremen"], rmse["binned_mean"]), rmse
    assert report["default"] == "gp" or (report["default"] == "blend"
                                         and report["blend"]["weight"] >= 0.5), report
    served = report["served_places"]
    assert set(served) == set(FORECASTERS)
    assert served["gp"] + served["blend"] > 0.5 * sum(served.values()), served
    assert f"serving {report['default']}" in fitted.status()


def test_intervals_on_overdispersed_counts_are_calibrated_on_the_held_out_days():
    train = place_tables(DAYS, seed=2, dispersion=2.0)
    test = later_days(place_tables(DAYS + 4, seed=3, dispersion=2.0), DAYS)
    model = TrafficGP(n_inducing=8, n_steps=60, batch_size=256, eval_every=20, hourly=False,
                      likelihood="poisson", profile="daily", refit_steps=10,
                      random_state=0).fit(train)
    cal = model.serving_.calibration
    assert 0.85 <= cal.coverage <= 0.95 and cal.dispersion is not None
    low, high = model.predict_interval(test.x, test.y, test.t)
    covered = np.mean((test.count >= low) & (test.count <= high))
    assert 0.85 <= covered <= 0.95, (covered, cal)
    # the same forecast with Poisson counts (the trained likelihood) covers far less
    mean, var = model.predict_latent(test.x, test.y, test.t)
    from traffic_gp import predictive
    plain = predictive.interval(0.9, mean + cal.latent_variance / 2,
                                np.maximum(var - cal.latent_variance, 1e-12), 1.0, None)
    assert np.mean((test.count >= plain[0]) & (test.count <= plain[1])) < 0.8
