"""Settings chosen on the user's own data: the candidates, the choice on the most recent days, and
its report in `status()`, the saved model and the NumPy posterior."""
import numpy as np
import pytest

from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_header
from traffic_gp.posterior import PosteriorSnapshot
from traffic_gp.selection import hourly_cycle_visible, options, shortest_period

# candidates screened for 20 steps each (eager steps, about 0.1 CPU-s apiece): the weekly profile
# wins its screen by far more (held-out log density about -1.6 against -2.2) than such short
# screens change
SMALL = dict(n_inducing=20, n_steps=120, batch_size=256, eval_every=20, screen_inducing=12,
             screen_steps=20, refit_steps=20, random_state=0)


def weekday_sensors(days: int = 21, seed: int = 0) -> Observations:
    """Hourly counts at four sensors: busy around noon on weekdays, nearly nobody at weekends
    (day 0 is a Monday). 21 days: the last 4 are held out (Thursday to Sunday), 17 fit."""
    rng = np.random.default_rng(seed)
    t = np.arange(days * 24) + 0.5
    weekend = np.mod(t, 168.0) >= 120.0
    rows = []
    for place, scale in enumerate((1.0, 0.6, 1.4, 0.8)):
        rate = np.where(weekend, 0.3, scale * (2.0 + 30.0 * np.exp(-((np.mod(t, 24) - 12) / 3) ** 2)))
        rows.append(Observations(np.full(t.size, 10.0 * place), np.zeros(t.size), t,
                                 np.ones(t.size), rng.poisson(rate)))
    return Observations.concat(rows)


@pytest.fixture(scope="module")
def chosen():
    return TrafficGP(likelihood="poisson", weekly=False, **SMALL).fit(weekday_sensors())


def test_the_weekly_profile_is_chosen_where_weekends_differ(chosen):
    report = chosen.selection_
    assert set(report["candidates"]) == {f"poisson, profile {p}, xy, daily kernel"
                                         for p in ("none", "daily", "weekly")}
    assert chosen.settings_["profile"] == "weekly" and report["chosen"].endswith(
        "profile weekly, xy, daily kernel")
    scores = {key: value["log_density"] for key, value in report["candidates"].items()}
    assert max(scores, key=scores.get) == report["chosen"]
    assert "by held-out log density" in report["reason"] and "searched profile" in report["reason"]
    assert chosen.split_["held_out_days"] == 4 and chosen.split_["days"] == 21
    # the choice is worth it on the following week: the weekend is forecast empty
    test = weekday_sensors(28, seed=1).subset(np.nonzero(weekday_sensors(28).t >= 21 * 24)[0])
    weekend = np.mod(test.t, 168.0) >= 120.0
    assert np.mean(chosen.predict(test.x[weekend], test.y[weekend], test.t[weekend])) < 1.0


def test_the_choice_and_why_are_in_the_status_the_file_and_the_numpy_posterior(chosen, tmp_path):
    status = chosen.status()
    assert chosen.selection_["reason"] in status and "serving" in status
    path = chosen.save(tmp_path / "chosen.npz")
    header = read_header(path)
    assert header["selection"]["chosen"] == chosen.selection_["chosen"]
    assert header["settings"]["profile"] == "weekly" and header["params"]["profile"] == "auto"
    snapshot = PosteriorSnapshot.load(path)
    assert snapshot.status() == status
    loaded = TrafficGP.load(path)
    x, y, t = np.zeros(5), np.zeros(5), np.linspace(100.0, 150.0, 5)
    np.testing.assert_allclose(loaded.predict(x, y, t), chosen.predict(x, y, t), rtol=1e-9)
    np.testing.assert_allclose(snapshot.predict(x, y, t), chosen.predict(x, y, t), rtol=1e-6)


def test_candidates_follow_what_the_data_can_show():
    params = dict(likelihood="auto", profile="auto", spatial_inputs="auto", weekly="auto")
    short = options(params, has_map=True, fit_days=8)
    assert short == {"likelihood": ["poisson", "negbin"], "profile": ["none", "daily"],
                     "spatial_inputs": ["geodesic", "xy"], "weekly": [False]}
    long = options(params, has_map=False, fit_days=14)
    assert long["profile"] == ["none", "daily", "weekly"] and long["weekly"] == [False, True]
    assert long["spatial_inputs"] == ["xy"]
    fixed = options(dict(params, likelihood="negbin", profile="none"), has_map=False, fit_days=3)
    assert fixed["likelihood"] == ["negbin"] and fixed["profile"] == ["none"]


def test_counts_taken_once_an_hour_drop_the_hourly_cycle():
    hourly = np.arange(200) + 0.5
    assert not hourly_cycle_visible(hourly) and shortest_period(hourly) == 2.0
    spread = np.random.default_rng(0).uniform(0, 48, 200)
    assert hourly_cycle_visible(spread) and shortest_period(spread) == pytest.approx(1 / 6)


def test_without_a_hold_out_the_defaults_are_fitted_and_said():
    rows = weekday_sensors(21).subset(np.arange(0, 120, 2))      # 60 rows: no hold-out
    model = TrafficGP(n_inducing=10, n_steps=5, validation_fraction=0.2, hourly=False).fit(rows)
    assert model.split_ is None and model.serving_ is None
    assert model.settings_["likelihood"] == "negbin" and model.settings_["profile"] == "none"
    assert "no time-ordered hold-out" in model.status()
