"""Every analytic derivative of the learning core against finite differences: features (jets),
the trajectory reward's action gradient g and Hessian H (with the second-order dynamics term),
the reverse pass of the Laplace likelihood, and the GP reward's feature derivatives."""
import numpy as np
import pytest

from lfd_controller.features import FeatureSet, Task
from lfd_controller.laplace import DemoDynamics, laplace_log_likelihood, noisy_laplace_log_likelihood
from lfd_controller.planner import trajectory_reward
from lfd_controller.rewards import GPReward, LinearReward, RewardDerivatives
from robot_sim.scenarios import load_scenario


def _random_trajectory(seed, count=12):
    rng = np.random.default_rng(seed)
    scenario = load_scenario("moving_obstacle")
    start = np.array([-1.8, -0.4, 0.3, 0.2, 0.1])
    actions = np.column_stack([rng.uniform(0.1, 0.7, count), rng.uniform(-1.5, 1.5, count)])
    return scenario, start, actions


@pytest.mark.parametrize("person", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_feature_gradients_and_hessians_match_finite_differences(seed, person):
    rng = np.random.default_rng(seed)
    features = FeatureSet(forward_command=person, obstacle_facing=person, goal_slowing=person,
                          goal_progress=person, proximity_widths=(0.5, 0.8) if person else (),
                          predicted=1.0 if person else 0.0, goal_distance=not person,
                          state_effort=person)
    task = Task.from_scenario(load_scenario("moving_obstacle"))
    states = np.column_stack([rng.uniform(-2.5, 0.5, 6), rng.uniform(-1.2, 1.2, 6),
                              rng.uniform(-3, 3, 6), rng.uniform(-0.5, 0.5, 6), rng.uniform(-1, 1, 6)])
    actions, times = rng.uniform(-1, 1, (6, 2)), rng.uniform(0, 8, 6)
    fv = features.evaluate(states, actions, times, task)
    eps = 1e-5
    for i in range(5):
        step = np.zeros(5)
        step[i] = eps
        up = features.evaluate(states + step, actions, times, task)
        down = features.evaluate(states - step, actions, times, task)
        np.testing.assert_allclose(fv.state_jac[:, :, i], (up.state - down.state) / (2 * eps), atol=1e-7)
        np.testing.assert_allclose(fv.state_hess[:, :, :, i], (up.state_jac - down.state_jac) / (2 * eps),
                                   atol=1e-6)
    for i in range(2):
        step = np.zeros(2)
        step[i] = eps
        up = features.evaluate(states, actions + step, times, task)
        down = features.evaluate(states, actions - step, times, task)
        numeric = (up.control - down.control) / (2 * eps)
        np.testing.assert_allclose(fv.control_jac[:, :, i], numeric, atol=1e-7)
    # the first-order evaluation (planning) gives the same values and gradients
    first = features.evaluate(states, actions, times, task, order=1)
    assert first.state_hess is None
    np.testing.assert_allclose(first.state, fv.state)
    np.testing.assert_allclose(first.state_jac, fv.state_jac)


def test_progress_is_speed_toward_the_goal_and_prediction_looks_ahead():
    """Values against hand computation: goal_progress = v cos(bearing) far from the goal;
    obstacle_predicted peaks where robot and obstacle will meet `predicted` s ahead."""
    features = FeatureSet(goal_distance=False, goal_progress=True, predicted=1.0)
    # goal (0, 0); obstacle (-1.3, -1.2 + 0.25 t)
    task = Task.from_scenario(load_scenario("moving_obstacle"))
    states = np.array([[-30.0, 0.0, 0.0, 0.4, 0.0],      # heading straight at the goal
                       [-30.0, 0.0, np.pi / 3, 0.4, 0.0],   # 60 degrees off
                       [-1.3, -0.7, 0.0, 0.0, 0.0]])      # standing where the obstacle is at t = 2 s
    fv = features.evaluate(states, np.zeros((3, 2)), np.array([0.0, 0.0, 1.0]), task)
    progress = fv.state[:, features.state_names.index("goal_progress")]
    assert progress[0] == pytest.approx(0.4, rel=1e-3) and progress[1] == pytest.approx(0.2, rel=1e-3)
    assert fv.state[2, features.state_names.index("obstacle_predicted")] == pytest.approx(1.0)


def _rewards():
    scenario = load_scenario("moving_obstacle")
    rng = np.random.default_rng(5)
    linear = LinearReward([-1.0, 0.3, -6.0, -1.0, -0.3, -0.05])
    gp = GPReward(rng.uniform(0, 1, (15, 4)), rng.normal(0, 1, 15), [0.5, 0.7, 0.3, 0.4], [-0.3, -0.1])
    return scenario, {"linear": linear, "gp": gp}


@pytest.mark.parametrize("kind", ["linear", "gp"])
def test_action_gradient_and_full_hessian_match_finite_differences(kind):
    scenario, rewards = _rewards()
    reward = rewards[kind]
    _, start, actions = _random_trajectory(1)
    model, task = scenario.model(), Task.from_scenario(scenario)
    dyn = DemoDynamics(model, start, actions, 0.7, task)
    rd = reward.derivatives(dyn.states, actions, dyn.times, task)
    g, hess = dyn.grad_hess(rd)
    eps = 1e-5
    numeric_g, numeric_h = np.zeros_like(g), np.zeros_like(hess)
    flat = actions.reshape(-1)
    for i in range(len(flat)):
        up, down = flat.copy(), flat.copy()
        up[i] += eps
        down[i] -= eps
        value_up, grad_up = trajectory_reward(reward, model, task, start, 0.7, up.reshape(-1, 2))
        value_down, grad_down = trajectory_reward(reward, model, task, start, 0.7, down.reshape(-1, 2))
        numeric_g[i] = (value_up - value_down) / (2 * eps)
        numeric_h[:, i] = (grad_up - grad_down).reshape(-1) / (2 * eps)
    np.testing.assert_allclose(g, numeric_g, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(hess, numeric_h, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(hess, hess.T, atol=1e-10)


def test_hessian_without_the_second_order_dynamics_term_is_wrong():
    """The second-order term matters: dropping it (lambda = 0) misses the finite-difference Hessian."""
    scenario, rewards = _rewards()
    _, start, actions = _random_trajectory(2)
    model, task = scenario.model(), Task.from_scenario(scenario)
    dyn = DemoDynamics(model, start, actions, 0.0, task)
    rd = rewards["linear"].derivatives(dyn.states, actions, dyn.times, task)
    _, full = dyn.grad_hess(rd)
    dyn.F = np.zeros_like(dyn.F)
    _, first_order_only = dyn.grad_hess(rd)
    assert np.abs(full - first_order_only).max() > 1e-2 * np.abs(full).max()


def test_reverse_pass_of_the_likelihood_matches_finite_differences():
    scenario, rewards = _rewards()
    _, start, actions = _random_trajectory(3)
    model, task = scenario.model(), Task.from_scenario(scenario)
    dyn = DemoDynamics(model, start, actions, 0.0, task)
    rd = rewards["linear"].derivatives(dyn.states, actions, dyn.times, task)
    _, hess = dyn.grad_hess(rd)
    shift = max(0.0, np.linalg.eigvalsh(hess).max()) + 1.0
    rd.ruu = rd.ruu - shift * np.eye(2)        # makes H negative definite around this point

    def likelihood(r):
        g, hess = dyn.grad_hess(r)
        return laplace_log_likelihood(g, hess, derivatives=True)

    lap = likelihood(rd)
    assert lap is not None
    grads = dyn.backprop(lap.h_vec, lap.m_mat)
    rng = np.random.default_rng(0)
    for name in ("rx", "ru", "rxx", "ruu"):
        direction = rng.standard_normal(getattr(rd, name).shape)
        if name in ("rxx", "ruu"):
            direction = direction + np.swapaxes(direction, 1, 2)
        eps = 1e-6
        values = []
        for sign in (1, -1):
            moved = RewardDerivatives(rd.value, rd.rx.copy(), rd.ru.copy(), rd.rxx.copy(), rd.ruu.copy())
            setattr(moved, name, getattr(rd, name) + sign * eps * direction)
            values.append(likelihood(moved).value)
        numeric = (values[0] - values[1]) / (2 * eps)
        analytic = np.sum(getattr(grads, name) * direction)
        assert analytic == pytest.approx(numeric, rel=1e-5, abs=1e-6), name


def test_laplace_likelihood_of_a_gaussian_is_its_log_density():
    """For a quadratic reward the Laplace approximation is exact: L = log N(0; -H^-1 g, -H^-1)."""
    rng = np.random.default_rng(1)
    root = rng.standard_normal((4, 4))
    hess = -(root @ root.T + 4 * np.eye(4))
    g = rng.standard_normal(4)
    cov = -np.linalg.inv(hess)
    mean = cov @ g
    expected = -0.5 * mean @ np.linalg.solve(cov, mean) - 0.5 * np.log(np.linalg.det(2 * np.pi * cov))
    assert laplace_log_likelihood(g, hess).value == pytest.approx(expected, rel=1e-10)
    assert laplace_log_likelihood(g, -hess) is None       # not negative definite


def test_noisy_laplace_likelihood_is_the_gaussian_density_and_its_gradients_are_exact():
    """With action noise S: L = log N(0; -H^-1 g, -H^-1 + S) (exact for a quadratic reward), equal
    to the plain Laplace L for S -> 0; dL/dg, dL/dH, dL/dS against finite differences."""
    rng = np.random.default_rng(3)
    root = rng.standard_normal((4, 4))
    hess = -(root @ root.T + 2 * np.eye(4))
    g, noise = rng.standard_normal(4), rng.uniform(0.1, 0.5, 4)
    cov = -np.linalg.inv(hess) + np.diag(noise)
    mean = -np.linalg.inv(hess) @ g
    expected = -0.5 * mean @ np.linalg.solve(cov, mean) - 0.5 * np.log(np.linalg.det(2 * np.pi * cov))
    terms = noisy_laplace_log_likelihood(g, hess, noise)
    assert terms.value == pytest.approx(expected, rel=1e-10)
    assert noisy_laplace_log_likelihood(g, hess, np.zeros(4)).value == pytest.approx(
        laplace_log_likelihood(g, hess).value, rel=1e-10)
    eps = 1e-6
    for i in range(4):
        step = np.zeros(4)
        step[i] = eps
        numeric = (noisy_laplace_log_likelihood(g + step, hess, noise, derivatives=False).value
                   - noisy_laplace_log_likelihood(g - step, hess, noise, derivatives=False).value)
        assert terms.h_vec[i] == pytest.approx(numeric / (2 * eps), rel=1e-5)
        numeric = (noisy_laplace_log_likelihood(g, hess, noise + step, derivatives=False).value
                   - noisy_laplace_log_likelihood(g, hess, noise - step, derivatives=False).value)
        assert terms.noise_grad[i] == pytest.approx(numeric / (2 * eps), rel=1e-5)
    direction = rng.standard_normal((4, 4))
    direction = direction + direction.T
    numeric = (noisy_laplace_log_likelihood(g, hess + eps * direction, noise, derivatives=False).value
               - noisy_laplace_log_likelihood(g, hess - eps * direction, noise, derivatives=False).value)
    assert np.sum(terms.m_mat * direction) == pytest.approx(numeric / (2 * eps), rel=1e-5)


def test_gp_feature_derivatives_match_finite_differences():
    _, rewards = _rewards()
    gp = rewards["gp"]
    phi = np.random.default_rng(2).uniform(0, 1, (5, 4))
    value, grad, hess = gp.feature_derivatives(phi)
    eps = 1e-6
    for d in range(4):
        step = np.zeros(4)
        step[d] = eps
        up, down = gp.feature_derivatives(phi + step), gp.feature_derivatives(phi - step)
        np.testing.assert_allclose(grad[:, d], (up[0] - down[0]) / (2 * eps), atol=1e-6)
        np.testing.assert_allclose(hess[:, :, d], (up[1] - down[1]) / (2 * eps), atol=1e-6)
