"""Baselines: FreMEn recovers a known periodic signal; binned means; errors."""
import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from robot_common.maps import FREE, GridMap
from traffic_gp.baselines import BinnedMean, FreMEn
from traffic_gp.errors import NotFittedError
from traffic_gp.observations import Observations


@pytest.fixture(scope="module")
def one_cell():
    return CellGrid(GridMap(np.full((2, 2), FREE, np.int8), 0.5), 2)     # one 1 x 1 m cell


def signal(t):
    return 2.0 + 0.8 * np.cos(2 * np.pi * t / 24 - 1.0) + 0.5 * np.cos(2 * np.pi * t / 8 + 0.3)


def observe(rng, n, rate_fn, span=24 * 20, expo_range=(2.0, 6.0)):
    t = np.sort(rng.uniform(0, span, n))
    expo = rng.uniform(*expo_range, n)
    return Observations(np.full(n, 0.5), np.full(n, 0.5), t, expo, rng.poisson(rate_fn(t) * expo))


def test_fremen_finds_the_periods_amplitudes_and_phases_of_a_known_signal(one_cell):
    obs = observe(np.random.default_rng(0), 30000, signal)
    model = FreMEn(one_cell, order=2).fit(obs)
    periods = sorted(2 * np.pi / model.omega_[0])
    assert periods == pytest.approx([8.0, 24.0])
    amplitude = dict(zip(np.round(2 * np.pi / model.omega_[0]), model.amplitude_[0]))
    assert amplitude[24.0] == pytest.approx(0.8, rel=0.1)
    assert amplitude[8.0] == pytest.approx(0.5, rel=0.15)
    t = np.linspace(0, 24, 97)
    np.testing.assert_allclose(model.predict(0.5, 0.5, t), signal(t), atol=0.15)
    assert model.set_order(0).predict(0.5, 0.5, 3.0) == pytest.approx(2.0, rel=0.03)


def test_fremen_balance_term_removes_the_bias_of_uneven_sampling(one_cell):
    rng = np.random.default_rng(2)
    t = rng.uniform(0, 24 * 20, 60000)
    t = t[np.mod(t, 24) < 12 + 12 * (rng.random(t.size) < 0.2)]   # mornings watched 5x more
    expo = np.full(t.size, 3.0)
    flat = Observations(np.full(t.size, 0.5), np.full(t.size, 0.5), t, expo,
                        rng.poisson(1.5 * expo))
    model = FreMEn(one_cell, order=3).fit(flat)
    assert np.all(model.amplitude_ < 0.1), "a constant rate has no periodic component"


def test_binned_mean_averages_per_bin_and_falls_back(one_cell):
    obs = Observations([0.5, 0.5, 0.5], [0.5] * 3, [1.1, 1.2, 5.5], [1.0, 3.0, 2.0], [2, 2, 8])
    model = BinnedMean(one_cell, bin_minutes=60).fit(obs)
    assert model.predict(0.5, 0.5, 1.9) == pytest.approx(1.0)        # (2 + 2) / (1 + 3)
    assert model.predict(0.5, 0.5, 5.0) == pytest.approx(4.0)
    assert model.predict(0.5, 0.5, 9.0) == pytest.approx(12 / 6.0)    # unseen bin: cell mean
    assert model.predict(5.0, 5.0, 1.0) == pytest.approx(12 / 6.0)    # outside: global mean


def test_baseline_errors(one_cell):
    with pytest.raises(NotFittedError):
        FreMEn(one_cell).predict(0.5, 0.5, 1.0)
    with pytest.raises(ConfigError, match="order"):
        FreMEn(one_cell, order=-1)
    with pytest.raises(ConfigError, match="bin_minutes"):
        BinnedMean(one_cell, bin_minutes=0)
