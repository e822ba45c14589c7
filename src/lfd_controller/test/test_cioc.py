"""Continuous inverse optimal control: likelihood gradients, recovery of a known reward, the
augmented-Lagrangian handling of Hessians that are not negative definite, and bad inputs."""
import numpy as np
import pytest

from lfd_controller.cioc import LinearCIOC, feature_terms, prepare
from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError, NotFittedError
from lfd_controller.gp_cioc import GPCIOC
from lfd_controller.rewards import reward_from_dict


def _cosine(a, b):
    return float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_linear_likelihood_gradient_matches_finite_differences(expert_demos, true_weights):
    terms = [feature_terms(dyn, LinearCIOC().features) for dyn in prepare(expert_demos[:2])]
    weights, beta = true_weights * 3.0, 0.5
    value, d_w, d_beta = LinearCIOC.log_likelihood(terms, weights, beta)
    eps = 1e-6
    for k in range(len(weights)):
        step = np.zeros_like(weights)
        step[k] = eps
        numeric = (LinearCIOC.log_likelihood(terms, weights + step, beta, False)[0]
                   - LinearCIOC.log_likelihood(terms, weights - step, beta, False)[0]) / (2 * eps)
        assert d_w[k] == pytest.approx(numeric, rel=1e-5, abs=1e-5)
    numeric_beta = (LinearCIOC.log_likelihood(terms, weights, beta + eps, False)[0]
                    - LinearCIOC.log_likelihood(terms, weights, beta - eps, False)[0]) / (2 * eps)
    assert d_beta == pytest.approx(numeric_beta, rel=1e-5)


def test_noisy_likelihood_gradient_matches_finite_differences(expert_demos, true_weights):
    terms = [feature_terms(dyn, LinearCIOC().features) for dyn in prepare(expert_demos[:2])]
    weights, beta, noise = true_weights * 3.0, 0.5, np.array([0.01, 0.04])
    value, grad, d_beta = LinearCIOC.log_likelihood(terms, weights, beta, noise=noise)
    params = np.concatenate([weights, noise])
    eps = 1e-6

    def value_at(p, b=beta):
        return LinearCIOC.log_likelihood(terms, p[:-2], b, False, noise=p[-2:])[0]
    for k in range(len(params)):
        step = np.zeros_like(params)
        step[k] = eps
        numeric = (value_at(params + step) - value_at(params - step)) / (2 * eps)
        assert grad[k] == pytest.approx(numeric, rel=1e-5, abs=1e-5)
    numeric_beta = (value_at(params, beta + eps) - value_at(params, beta - eps)) / (2 * eps)
    assert d_beta == pytest.approx(numeric_beta, rel=1e-5)


def test_linear_cioc_recovers_the_known_reward_direction(expert_demos, true_weights):
    model = LinearCIOC(random_state=0).fit(expert_demos)
    assert _cosine(model.weights_, true_weights) > 0.98
    # the sign of every weight is right: goal attracts, obstacle repels, effort costs
    assert np.all(np.sign(model.weights_) == np.sign(true_weights))
    assert model.beta_ < 1e-3
    one_demo = LinearCIOC(random_state=0).fit(expert_demos[:1])
    assert model.score(expert_demos) > one_demo.score(expert_demos) - 1e-6
    assert reward_from_dict(model.reward_.to_dict()).weights.tolist() == model.weights_.tolist()


def test_random_demonstrations_do_not_recover_the_reward(static_scenario, true_weights):
    """Learning is driven by the demonstrations: random drives give a different reward."""
    rng = np.random.default_rng(4)
    starts = static_scenario.sample_starts(6, seed=11)
    demos = [Demonstration(static_scenario, s, np.column_stack([rng.uniform(0, 0.6, 40),
                                                                rng.uniform(-1.5, 1.5, 40)]))
             for s in starts]
    model = LinearCIOC(random_state=0).fit(demos)
    assert _cosine(model.weights_, true_weights) < 0.9


def test_indefinite_hessian_is_regularised_and_the_regulariser_driven_to_zero(expert_demos, true_weights):
    """With the weights' signs flipped H is positive definite: no Laplace approximation without
    beta; the augmented Lagrangian starts from such a point and still ends with beta ~ 0."""
    terms = [feature_terms(dyn, LinearCIOC().features) for dyn in prepare(expert_demos)]
    assert LinearCIOC.log_likelihood(terms, -true_weights, 0.0, False) is None
    eig = max(np.linalg.eigvalsh(np.tensordot(-true_weights, hs, axes=1)).max() for _, hs in terms)
    assert LinearCIOC.log_likelihood(terms, -true_weights, eig + 1.0, False) is not None

    from lfd_controller.cioc import AugmentedLagrangian

    solver = AugmentedLagrangian(lambda w, b: LinearCIOC.log_likelihood(terms, w, b), outer=8)
    weights, beta, _ = solver.run(-true_weights, eig + 1.0, lambda w: (-5e-4 * w @ w, -1e-3 * w))
    assert beta < 1e-3
    assert LinearCIOC.log_likelihood(terms, weights, 0.0, False) is not None
    assert _cosine(weights, true_weights) > 0.95


def test_gp_objective_gradient_matches_finite_differences(expert_demos):
    learner = GPCIOC(max_inducing=12, random_state=0)
    learner._setup(expert_demos[:2])
    params = learner.initial_params(expert_demos[:2])
    params = params + 0.05 * np.random.default_rng(0).standard_normal(len(params))
    beta = 1.0
    while learner.objective(params, beta) is None:
        beta *= 2.0
    value, grad, _ = learner.objective(params, beta)
    eps = 1e-4
    for i in range(len(params)):
        step = np.zeros_like(params)
        step[i] = eps
        numeric = (learner.objective(params + step, beta)[0]
                   - learner.objective(params - step, beta)[0]) / (2 * eps)
        assert grad[i] == pytest.approx(numeric, rel=1e-3, abs=1e-3), i


def test_gp_cioc_learns_a_reward_that_ranks_states_like_the_true_one(expert_demos, static_scenario):
    from lfd_controller.expert import true_reward
    from lfd_controller.features import Task

    learner = GPCIOC(max_inducing=30, max_iter=60, outer_iterations=3, random_state=0).fit(expert_demos)
    assert learner.beta_ < 1e-2
    task = Task.from_scenario(static_scenario)
    xs, ys = np.meshgrid(np.linspace(-2.6, -0.2, 13), np.linspace(-0.9, 0.9, 9))
    yaw = np.arctan2(-ys, -xs)
    states = np.column_stack([xs.ravel(), ys.ravel(), yaw.ravel(), np.zeros((xs.size, 2))])
    times = np.zeros(len(states))
    learned = learner.predict(states, times, task)
    truth = true_reward().state_reward(states, times, task)
    assert np.corrcoef(learned, truth)[0, 1] > 0.8
    data = learner.reward_.to_dict()
    np.testing.assert_allclose(reward_from_dict(data).state_reward(states, times, task), learned)


def test_bad_inputs_get_clear_errors(static_scenario):
    with pytest.raises(DemonstrationError, match="no demonstrations"):
        LinearCIOC().fit([])
    with pytest.raises(DemonstrationError, match="shape"):
        Demonstration(static_scenario, np.zeros(5), np.zeros((1, 2)))
    with pytest.raises(DemonstrationError, match="finite"):
        Demonstration(static_scenario, np.zeros(5), np.full((4, 2), np.nan))
    with pytest.raises(NotFittedError):
        LinearCIOC().score([])
    with pytest.raises(NotFittedError):
        GPCIOC().predict(np.zeros((1, 5)), np.zeros(1), None)
