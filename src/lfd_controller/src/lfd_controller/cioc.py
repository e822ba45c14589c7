"""Continuous inverse optimal control with a linear reward (Levine and Koltun 2012; no ROS).

For a linear reward r = w . f, the action gradient and Hessian of the trajectory reward are
g = sum_k w_k g_k and H = sum_k w_k H_k, with per-feature g_k, H_k computed once per demonstration
(laplace.py; including the second-order dynamics term). The weights maximise the summed Laplace
log-likelihood L(w) with the analytic gradient
    dL/dw_k = h . g_k + <M, H_k>,  h = H^-1 g,  M = 1/2 (H^-1 - h h^T).
H must be negative definite for the Laplace approximation; the learner uses H - beta I with a
regulariser beta >= 0 that an augmented Lagrangian drives to zero (constraint beta = 0).

With `action_noise`, the demonstrated commands are modelled as locally optimal commands plus
Gaussian noise (a person's quantised stick and hand), L = log N(U_demo; U*, (-H)^-1 + S)
(laplace.noisy_laplace_log_likelihood); the noise variances S (one for v_cmd, one for w_cmd) are
given or learned with the weights by maximum likelihood.
"""
import logging
import time
from typing import List, Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from lfd_controller.demos import Demonstration, check_same_dt
from lfd_controller.errors import LearningError, NotFittedError
from lfd_controller.features import FeatureSet, Task
from lfd_controller.laplace import DemoDynamics, laplace_log_likelihood, noisy_laplace_log_likelihood
from lfd_controller.rewards import LinearReward, RewardDerivatives

LOG = logging.getLogger(__name__)
INFEASIBLE = 1e12
NOISE_VARIANCE_BOUNDS = (1e-5, 1.0)   # (m/s)^2 and (rad/s)^2 per command


def command_jitter(demos: Sequence[Demonstration], window: int = 5) -> np.ndarray:
    """Variance of the commands about their `window`-step centred moving average (v, w): a
    starting guess of the action noise."""
    residuals = []
    kernel = np.ones(window) / window
    for demo in demos:
        padded = np.pad(demo.actions, ((window // 2, window - 1 - window // 2), (0, 0)), mode="edge")
        smooth = np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in (0, 1)])
        residuals.append(demo.actions - smooth)
    low, high = NOISE_VARIANCE_BOUNDS
    return np.clip(np.var(np.vstack(residuals), axis=0), low, high)


def prepare(demos: Sequence[Demonstration]) -> List[DemoDynamics]:
    check_same_dt(demos)
    return [DemoDynamics(d.scenario.model(), d.start, d.actions, d.t0, Task.from_scenario(d.scenario))
            for d in demos]


def feature_terms(dyn: DemoDynamics, features: FeatureSet, terminal: float = 0.0,
                  second_order: bool = True):
    """Per-feature g_k (K, n) and H_k (K, n, n) of one demonstration (terminal > 0: the last
    step's features count 1 + terminal times, as in the receding-horizon planner's objective;
    second_order False: H without the dynamics' second-order term)."""
    fv = features.evaluate(dyn.states, dyn.actions, dyn.times, dyn.task, order=2)
    if terminal:
        for values in (fv.state_jac, fv.state_hess, fv.control_jac, fv.control_hess):
            values[-1] *= 1.0 + terminal
    count, ks = dyn.T, fv.state.shape[1]
    gs, hs = [], []
    zeros_x, zeros_u = np.zeros((count, 5)), np.zeros((count, 2))
    for k in range(ks):
        rd = RewardDerivatives(None, fv.state_jac[:, k], zeros_u, fv.state_hess[:, k],
                               np.zeros((count, 2, 2)))
        g, h = dyn.grad_hess(rd, second_order)
        gs.append(g)
        hs.append(h)
    for c in range(fv.control.shape[1]):
        rd = RewardDerivatives(None, zeros_x, fv.control_jac[:, c], np.zeros((count, 5, 5)),
                               fv.control_hess[:, c])
        g, h = dyn.grad_hess(rd, second_order)
        gs.append(g)
        hs.append(h)
    return np.array(gs), np.array(hs)


class AugmentedLagrangian:
    """Maximise sum of L(params, beta) subject to beta = 0 (beta >= 0 keeps H - beta I negative
    definite while the parameters are still poor). `objective(params, beta)` returns
    (sum L, dL/dparams, dL/dbeta) or None when H - beta I is not negative definite."""

    def __init__(self, objective, *, outer: int = 6, max_iter: int = 300, tol: float = 1e-4,
                 penalty: float = 1.0, growth: float = 10.0):
        self.objective, self.outer, self.max_iter = objective, outer, max_iter
        self.tol, self.penalty, self.growth = tol, penalty, growth

    def run(self, params0: np.ndarray, beta0: float, prior=None, progress=None, bounds=None):
        params, beta = np.asarray(params0, float).copy(), float(beta0)
        multiplier, penalty = 0.0, self.penalty
        iterations = 0
        for _ in range(self.outer):
            def negative(z, multiplier=multiplier, penalty=penalty):
                result = self.objective(z[:-1], z[-1])
                if result is None or not (np.isfinite(result[0]) and np.all(np.isfinite(result[1]))):
                    grad = np.zeros_like(z)
                    grad[-1] = -INFEASIBLE
                    return INFEASIBLE, grad
                value, d_params, d_beta = result
                value, d_params = -value, -d_params
                if prior is not None:
                    p_value, p_grad = prior(z[:-1])
                    value, d_params = value - p_value, d_params - p_grad
                value += multiplier * z[-1] + 0.5 * penalty * z[-1] ** 2
                return value, np.append(d_params, -d_beta + multiplier + penalty * z[-1])
            box = list(bounds or [(None, None)] * len(params)) + [(0.0, None)]
            res = minimize(negative, np.append(params, beta), jac=True, method="L-BFGS-B",
                           bounds=box, options={"maxiter": self.max_iter, "gtol": 1e-6})
            iterations += res.nit
            params, beta = res.x[:-1], float(res.x[-1])
            if progress is not None:
                progress(-res.fun, beta)
            if beta < self.tol:
                break
            multiplier += penalty * beta
            penalty *= self.growth
        return params, beta, iterations


class LinearCIOC:
    """Learns linear reward weights from locally optimal demonstrations (sklearn-style).

    Args:
        features: the FeatureSet (default FeatureSet()).
        weight_prior: precision of a Gaussian prior on the weights (fixes the reward's scale when
            demonstrations are exactly optimal, where L grows without bound with the scale).
        outer_iterations, max_iter: augmented-Lagrangian rounds and L-BFGS iterations per round.
        random_state: seeds the initial weights' small jitter.
        signs: {feature name: -1 or +1}: weights constrained to that sign (a prior on what the
            features mean, e.g. being far from the goal is never rewarded); default none.
        action_noise: None (the paper's Laplace likelihood), "learn" (Gaussian command noise,
            variances learned with the weights, started at command_jitter) or (std v_cmd, std
            w_cmd) fixed.
        terminal: extra weight of each demonstration's last step (the planner's cost-to-go
            estimate; for demonstrations cut into windows that end mid-drive).
        second_order: include the dynamics' second-order term in H (the paper's exact Hessian;
            default). False: the Gauss-Newton H. The robot's smooth acceleration limit is strongly
            curved exactly where a person's stick ramps or jitters the speed, which makes any
            reward with a speed-dependent state term convex in the command there (H indefinite),
            so the exact-H learner can only keep the effort weight dominant.
    Fitted attributes: weights_, reward_, beta_ (final regulariser; 0 = none needed),
    log_likelihood_ (per demonstration), n_iter_, fit_time_, noise_std_ (None without noise).
    """

    def __init__(self, features: Optional[FeatureSet] = None, *, weight_prior: float = 1e-3,
                 outer_iterations: int = 6, max_iter: int = 300, random_state=None,
                 signs: Optional[dict] = None, action_noise=None, terminal: float = 0.0,
                 second_order: bool = True):
        self.features = features or FeatureSet()
        if not (action_noise is None or action_noise == "learn"
                or (len(action_noise) == 2 and all(float(v) > 0 for v in action_noise))):
            raise LearningError(f"action_noise must be None, 'learn' or two positive stds, got "
                                f"{action_noise!r}")
        self.action_noise = action_noise
        if not terminal >= 0:
            raise LearningError(f"terminal weight must be >= 0, got {terminal!r}")
        self.terminal = float(terminal)
        self.second_order = bool(second_order)
        self.signs = dict(signs or {})
        unknown = sorted(set(self.signs) - set(self.features.names))
        if unknown or any(v not in (-1, 1) for v in self.signs.values()):
            raise LearningError(f"weight signs must map feature names {list(self.features.names)} to "
                                f"-1 or +1, got {signs!r}")
        self.weight_prior = weight_prior
        self.outer_iterations = outer_iterations
        self.max_iter = max_iter
        self.random_state = random_state

    def _terms(self, demos):
        return [feature_terms(dyn, self.features, self.terminal, self.second_order)
                for dyn in prepare(demos)]

    @staticmethod
    def log_likelihood(terms, weights, beta: float = 0.0, derivatives: bool = True, noise=None):
        """Summed L, dL/dw, dL/dbeta (and dL/dnoise (2,) when `noise`, the command noise
        variances (v, w), is given) over precomputed per-feature terms; None if not ND."""
        total, d_w, d_beta = 0.0, np.zeros(len(weights)), 0.0
        d_noise = np.zeros(2)
        for gs, hs in terms:
            g, hess = weights @ gs, np.tensordot(weights, hs, axes=1)
            if noise is None:
                lap = laplace_log_likelihood(g, hess, beta=beta, derivatives=derivatives)
            else:
                lap = noisy_laplace_log_likelihood(g, hess, np.tile(noise, len(g) // 2), beta=beta,
                                                   derivatives=derivatives)
            if lap is None:
                return None
            total += lap.value
            if derivatives:
                d_w += gs @ lap.h_vec + np.einsum("ij,kij->k", lap.m_mat, hs)
                d_beta -= np.trace(lap.m_mat)
                if noise is not None:
                    d_noise += lap.noise_grad.reshape(-1, 2).sum(axis=0)
        if noise is None:
            return total, d_w, d_beta
        return total, np.concatenate([d_w, d_noise]), d_beta

    def initial_weights(self) -> np.ndarray:
        rng = np.random.default_rng(self.random_state)
        ks = len(self.features.state_names)
        control = [-1.0 if name.endswith("_effort") else 0.0 for name in self.features.control_names]
        return np.concatenate([0.01 * rng.standard_normal(ks), control])

    def _noise0(self, demos) -> Optional[np.ndarray]:
        if self.action_noise is None:
            return None
        if self.action_noise == "learn":
            return command_jitter(demos)
        return np.asarray(self.action_noise, float) ** 2

    def fit(self, demos: Sequence[Demonstration]) -> "LinearCIOC":
        started = time.monotonic()
        terms = self._terms(demos)
        weights0 = self.initial_weights()
        noise0 = self._noise0(demos)
        if self.log_likelihood(terms, weights0, 0.0, derivatives=False, noise=noise0) is None:
            raise LearningError("the initial reward has no negative definite Hessian")
        count = len(weights0)
        learn_noise = self.action_noise == "learn"

        def objective(params, beta):
            if not learn_noise:
                return self.log_likelihood(terms, params, beta, noise=noise0)
            variances = np.exp(params[count:])
            result = self.log_likelihood(terms, params[:count], beta, noise=variances)
            if result is None:
                return None
            value, grad, d_beta = result
            return value, np.concatenate([grad[:count], grad[count:] * variances]), d_beta

        def prior(params):
            w = params[:count]
            grad = np.zeros_like(params)
            grad[:count] = -self.weight_prior * w
            return -0.5 * self.weight_prior * w @ w, grad

        solver = AugmentedLagrangian(objective, outer=self.outer_iterations, max_iter=self.max_iter)
        bounds = [{-1: (None, 0.0), 1: (0.0, None)}.get(self.signs.get(name), (None, None))
                  for name in self.features.names]
        weights0 = np.array([np.clip(w, lo if lo is not None else -np.inf, hi if hi is not None else np.inf)
                             for w, (lo, hi) in zip(weights0, bounds)])
        params0 = weights0
        if learn_noise:
            params0 = np.concatenate([weights0, np.log(noise0)])
            bounds = bounds + [tuple(np.log(NOISE_VARIANCE_BOUNDS))] * 2
        params, beta, iterations = solver.run(params0, 0.0, prior, bounds=bounds)
        weights = params[:count]
        noise = np.exp(params[count:]) if learn_noise else noise0
        final = self.log_likelihood(terms, weights, beta, derivatives=False, noise=noise)
        if final is None or not np.all(np.isfinite(weights)):
            raise LearningError("inverse optimal control diverged")
        if beta > 1e-3:
            LOG.warning("the Hessian needed a regulariser beta=%.3g at the learned weights", beta)
        self.weights_, self.beta_, self.n_iter_ = weights, beta, iterations
        self.noise_std_ = None if noise is None else np.sqrt(noise)
        self.log_likelihood_ = final[0] / len(demos)
        self.reward_ = LinearReward(weights, self.features)
        self.fit_time_ = time.monotonic() - started
        return self

    def score(self, demos: Sequence[Demonstration]) -> float:
        """Mean Laplace log-likelihood per demonstration under the learned weights (no regulariser);
        -inf where the Hessian is not negative definite."""
        if not hasattr(self, "weights_"):
            raise NotFittedError("LinearCIOC is not fitted")
        noise = None if self.noise_std_ is None else self.noise_std_ ** 2
        result = self.log_likelihood(self._terms(demos), self.weights_, 0.0, derivatives=False,
                                     noise=noise)
        return -np.inf if result is None else result[0] / len(demos)
