"""The unicycle: limits hold, and its analytic first and second derivatives match finite differences."""
import numpy as np
import pytest

from robot_common.errors import ModelError
from robot_common.unicycle import Unicycle, UnicycleLimits, saturate, saturate_inverse


def test_saturation_is_identity_near_zero_bounded_and_invertible():
    z = np.linspace(-10, 10, 2001)
    value, first, _ = saturate(z, 0.6)
    assert np.all(np.abs(value) < 0.6) and np.all(first > 0)
    assert abs(saturate(0.01, 0.6)[0] - 0.01) < 1e-8
    np.testing.assert_allclose(saturate_inverse(value[::50], 0.6), z[::50], rtol=1e-6, atol=1e-9)
    with pytest.raises(ModelError, match="cannot invert"):
        saturate_inverse(0.7, 0.6)


def test_speeds_and_accelerations_stay_within_limits():
    limits = UnicycleLimits(v_max=0.5, w_max=1.5, a_max=0.8, alpha_max=3.0)
    model = Unicycle(0.1, limits)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-5, 5, size=(300, 2))
    states = model.rollout(np.zeros(5), actions)
    speeds = np.vstack([np.zeros((1, 2)), states[:, 3:]])
    assert np.all(np.abs(speeds[:, 0]) < 0.5) and np.all(np.abs(speeds[:, 1]) < 1.5)
    accel = np.diff(speeds, axis=0) / 0.1
    assert np.all(np.abs(accel[:, 0]) <= 0.8 + 1e-9) and np.all(np.abs(accel[:, 1]) <= 3.0 + 1e-9)


def test_straight_drive_covers_speed_times_time():
    model = Unicycle(0.1)
    states = model.rollout(np.zeros(5), np.tile([0.2, 0.0], (50, 1)))
    # after the short acceleration the robot moves at ~0.2 m/s along x, heading unchanged
    assert abs(states[-1, 3] - 0.2) < 1e-3 and abs(states[-1, 1]) < 1e-12
    assert 0.95 < states[-1, 0] < 1.0


def test_rollout_matches_batched_step():
    model = Unicycle(0.1)
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, size=(20, 2))
    states = model.rollout([0.3, -0.2, 0.5, 0.1, 0.0], actions)
    stepped = model.step(np.vstack([[0.3, -0.2, 0.5, 0.1, 0.0], states[:-1]]), actions)
    np.testing.assert_allclose(states, stepped, atol=1e-12)


def _finite_difference(model, z, eps=1e-6):
    jac = np.zeros((5, 7))
    for i in range(7):
        up, down = z.copy(), z.copy()
        up[i] += eps
        down[i] -= eps
        jac[:, i] = (model.step(up[:5], up[5:]) - model.step(down[:5], down[5:])) / (2 * eps)
    return jac


@pytest.mark.parametrize("seed", range(4))
def test_first_and_second_derivatives_match_finite_differences(seed):
    model = Unicycle(0.1)
    rng = np.random.default_rng(seed)
    # includes saturated commands (|u| beyond the limits) and large speed changes
    z = np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-0.5, 0.5, 2), rng.uniform(-1.5, 1.5, 2)])
    _, a_mat, b_mat, hess = model.step_derivatives(z[:5], z[5:])
    numeric = _finite_difference(model, z)
    np.testing.assert_allclose(np.concatenate([a_mat[0], b_mat[0]], axis=1), numeric, atol=1e-7)
    eps = 1e-5
    for i in range(7):
        up, down = z.copy(), z.copy()
        up[i] += eps
        down[i] -= eps
        ju = np.concatenate(model.step_derivatives(up[:5], up[5:], second=False)[1:3], axis=2)[0]
        jd = np.concatenate(model.step_derivatives(down[:5], down[5:], second=False)[1:3], axis=2)[0]
        np.testing.assert_allclose(hess[0, :, :, i], (ju - jd) / (2 * eps), atol=1e-6)
    assert np.allclose(hess, np.swapaxes(hess, 2, 3))


def test_command_for_speeds_reaches_reachable_speeds():
    model = Unicycle(0.1)
    state = np.array([0.0, 0.0, 0.0, 0.3, 0.2])
    command = model.command_for_speeds(state, 0.35, 0.0)
    reached = model.step(state, command)
    np.testing.assert_allclose(reached[3:], [0.35, 0.0], atol=1e-9)


@pytest.mark.parametrize("kwargs, message", [
    ({"dt": 0.0}, "dt must be positive"), ({"dt": float("nan")}, "dt must be positive")])
def test_bad_time_step_is_rejected(kwargs, message):
    with pytest.raises(ModelError, match=message):
        Unicycle(**kwargs)


def test_bad_limits_and_inputs_are_rejected():
    with pytest.raises(ModelError, match="v_max must be a positive"):
        UnicycleLimits(v_max=-1.0)
    model = Unicycle()
    with pytest.raises(ModelError, match="finite"):
        model.step([0, 0, 0, 0, float("inf")], [0, 0])
    with pytest.raises(ModelError, match="shape"):
        model.rollout(np.zeros(5), np.zeros((3, 3)))
    with pytest.raises(ModelError, match="end in 5 values"):
        model.step(np.zeros(4), np.zeros(2))
