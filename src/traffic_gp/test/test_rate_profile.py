"""RateProfile (the GP's per-place offset) and TrafficGP with `profile`: rates by hand, shrinkage,
bins, persistence; a GP whose places have shapes of the day that one smooth kernel over space
cannot share learns them through the profile."""
import numpy as np
import pytest

from robot_common.errors import ConfigError
from traffic_gp.errors import ModelFormatError
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.posterior import PosteriorSnapshot
from traffic_gp.rate_profile import RateProfile


def test_rates_are_counts_over_exposure_shrunk_toward_place_times_bin_shape():
    # place A (0, 0): Monday 08:00-09:00 twice (exposure 2 each, counts 10 and 6); place B
    # (100, 0): Monday 08:30 once (exposure 1, count 3) and Tuesday 10:00 (exposure 4, count 0)
    profile = RateProfile("weekly", 60.0, prior_exposure=1.0).update(
        [0, 0, 100, 100], [0, 0, 0, 0], [8.2, 8.7, 8.5, 24 + 10.5], [2, 2, 1, 4], [10, 6, 3, 0])
    total_rate = 19 / 9
    bin_a = (16 + 3 + total_rate) / (5 + 1)               # Monday 08-09, all places
    place_a = (16 + total_rate) / (4 + 1)
    expected = (16 + place_a * bin_a / total_rate) / (4 + 1)
    assert profile.log_rate(0, 0, 8.9)[0] == pytest.approx(np.log(expected))
    # Tuesday 10-11 at B: zero counts, shrunk toward B's rate x that bin's shape, not to log 0
    bin_tue = (0 + total_rate) / (4 + 1)
    place_b = (3 + total_rate) / (5 + 1)
    expected_b = (0 + place_b * bin_tue / total_rate) / (4 + 1)
    assert profile.log_rate(100, 0, 34.0)[0] == pytest.approx(np.log(expected_b))
    # an unknown place gets the bin's rate over all places; the week wraps
    assert profile.log_rate(50, 50, 168 + 8.1)[0] == pytest.approx(np.log(bin_a))


def test_bins_of_each_kind():
    daily, daytype, weekly = (RateProfile(kind, 30.0) for kind in ("daily", "daytype", "weekly"))
    t = np.array([0.2, 8.6, 24 + 8.6, 5 * 24 + 1.0, 6 * 24 + 23.9])   # Mon, Mon, Tue, Sat, Sun
    np.testing.assert_array_equal(daily.bins(t), [0, 17, 17, 2, 47])
    np.testing.assert_array_equal(daytype.bins(t), [0, 17, 17, 48 + 2, 96 + 47])
    np.testing.assert_array_equal(weekly.bins(t), [0, 17, 48 + 17, 240 + 2, 288 + 47])
    assert (daily.n_bins, daytype.n_bins, weekly.n_bins) == (48, 144, 336)


def test_saves_and_restores_exactly_and_refuses_bad_settings_and_arrays():
    rng = np.random.default_rng(0)
    profile = RateProfile("daytype").update(rng.integers(0, 5, 300), 0.0, rng.uniform(0, 168, 300),
                                            1.0, rng.poisson(3.0, 300))
    copy = RateProfile.from_arrays(profile.to_arrays())
    x, t = rng.integers(0, 7, 50), rng.uniform(0, 168, 50)
    np.testing.assert_array_equal(copy.log_rate(x, 0.0, t), profile.log_rate(x, 0.0, t))
    assert RateProfile.from_arrays({}) is None
    with pytest.raises(ConfigError, match="monthly"):
        RateProfile("monthly")
    with pytest.raises(ConfigError, match="bin_minutes=7"):
        RateProfile("daily", 7.0)
    arrays = dict(profile.to_arrays(), counts=np.zeros((2, 3)))
    with pytest.raises(ModelFormatError, match="shape"):
        RateProfile.from_arrays(arrays)


def two_places(weeks=3, seed=0):
    """Two places 300 m apart with opposite days (A busy in the morning, B in the evening),
    hourly negative-binomial counts."""
    rng = np.random.default_rng(seed)
    hours = np.arange(weeks * 168) + 0.5
    x, t = np.repeat([0.0, 300.0], hours.size), np.tile(hours, 2)
    day = np.mod(t, 24.0)
    morning, evening = np.exp(-0.5 * ((day - 8) / 1.5) ** 2), np.exp(-0.5 * ((day - 18) / 1.5) ** 2)
    rate = np.where(x == 0.0, 5 + 200 * morning + 20 * evening, 5 + 20 * morning + 200 * evening)
    counts = rng.poisson(rate * rng.gamma(20.0, 1 / 20.0, rate.size))
    return Observations(x, np.zeros_like(x), t, np.ones_like(x), counts), rate


def profiled_model(profile):
    """The GP itself, the baselines not compared (on these counts FreMEn forecasts the held-out
    days as well, so with them it would be served instead: `test_gp_margin.py`)."""
    return TrafficGP(n_inducing=20, hourly=False, n_steps=150, batch_size=256, profile=profile,
                     likelihood="negbin", weekly=False, spatial_lengthscale=30.0, random_state=0,
                     fallback=False)


@pytest.fixture(scope="module")
def profiled():
    return profiled_model("daily").fit(two_places()[0])


def test_a_profiled_gp_forecasts_each_places_own_day(profiled):
    """Two places far apart with opposite days: with the profile the forecast is within 12 %
    RMS of the true rates (the profile's own noise is about 8 %): the GP over the residual
    does not spoil the places' own shapes."""
    _, rate = two_places()
    t = np.tile(np.arange(24) + 0.5, 2)
    x = np.repeat([0.0, 300.0], 24)
    true = np.concatenate([rate[:24], rate[3 * 168: 3 * 168 + 24]])
    error = float(np.sqrt(np.mean((profiled.predict(x, 0.0, t) / true - 1.0) ** 2)))
    assert error < 0.12 and profiled.profile_ is not None


def test_a_profiled_model_saves_loads_and_learns_online(profiled, tmp_path):
    path = profiled.save(tmp_path / "p.npz")
    loaded, snapshot = TrafficGP.load(path), PosteriorSnapshot.load(path)
    x, t = np.array([0.0, 300.0, 150.0]), np.array([8.5, 18.5, 12.0])
    reference = profiled.predict_latent(x, 0.0, t)
    np.testing.assert_array_equal(loaded.predict_latent(x, 0.0, t)[0], reference[0])
    np.testing.assert_allclose(snapshot.predict_latent(x, 0.0, t)[0], reference[0], rtol=1e-6)
    # online: a new place C with its own busy hour appears; the profile learns it at once
    new_t = np.tile(np.arange(24) + 0.5, 7) + np.repeat(np.arange(7) * 24.0, 24)
    counts = np.where(np.mod(new_t, 24.0) == 12.5, 400, 10)
    new = Observations(np.full(new_t.size, 600.0), np.zeros(new_t.size), new_t,
                       np.ones(new_t.size), counts)
    loaded.partial_fit(new, n_steps=20)
    at_noon, at_night = loaded.predict([600.0, 600.0], 0.0, [12.5, 3.5])
    assert at_noon > 200 and at_night < 30
    with pytest.raises(ConfigError, match="profile='hourly'"):
        TrafficGP(profile="hourly").fit(new)
