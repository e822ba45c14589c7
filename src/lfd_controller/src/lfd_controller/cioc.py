"""Continuous inverse optimal control with a linear reward (Levine and Koltun 2012; no ROS).

For a linear reward r = w . f, the action gradient and Hessian of the trajectory reward are
g = sum_k w_k g_k and H = sum_k w_k H_k, with per-feature g_k, H_k computed once per demonstration
(laplace.py; including the second-order dynamics term). The weights maximise the summed Laplace
log-likelihood L(w) with the analytic gradient
    dL/dw_k = h . g_k + <M, H_k>,  h = H^-1 g,  M = 1/2 (H^-1 - h h^T).
H must be negative definite for the Laplace approximation; the learner uses H - beta I with a
regulariser beta >= 0 that an augmented Lagrangian drives to zero (constraint beta = 0).
"""
import logging
import time
from typing import List, Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from lfd_controller.demos import Demonstration, check_same_dt
from lfd_controller.errors import LearningError, NotFittedError
from lfd_controller.features import FeatureSet, Task
from lfd_controller.laplace import DemoDynamics, laplace_log_likelihood
from lfd_controller.rewards import LinearReward, RewardDerivatives

LOG = logging.getLogger(__name__)
INFEASIBLE = 1e12


def prepare(demos: Sequence[Demonstration]) -> List[DemoDynamics]:
    check_same_dt(demos)
    return [DemoDynamics(d.scenario.model(), d.start, d.actions, d.t0, Task.from_scenario(d.scenario))
            for d in demos]


def feature_terms(dyn: DemoDynamics, features: FeatureSet):
    """Per-feature g_k (K, n) and H_k (K, n, n) of one demonstration."""
    fv = features.evaluate(dyn.states, dyn.actions, dyn.times, dyn.task, order=2)
    count, ks = dyn.T, fv.state.shape[1]
    gs, hs = [], []
    zeros_x, zeros_u = np.zeros((count, 5)), np.zeros((count, 2))
    for k in range(ks):
        rd = RewardDerivatives(None, fv.state_jac[:, k], zeros_u, fv.state_hess[:, k],
                               np.zeros((count, 2, 2)))
        g, h = dyn.grad_hess(rd)
        gs.append(g)
        hs.append(h)
    for c in range(fv.control.shape[1]):
        rd = RewardDerivatives(None, zeros_x, fv.control_jac[:, c], np.zeros((count, 5, 5)),
                               fv.control_hess[:, c])
        g, h = dyn.grad_hess(rd)
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
    Fitted attributes: weights_, reward_, beta_ (final regulariser; 0 = none needed),
    log_likelihood_ (per demonstration), n_iter_, fit_time_.
    """

    def __init__(self, features: Optional[FeatureSet] = None, *, weight_prior: float = 1e-3,
                 outer_iterations: int = 6, max_iter: int = 300, random_state=None,
                 signs: Optional[dict] = None):
        self.features = features or FeatureSet()
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
        return [feature_terms(dyn, self.features) for dyn in prepare(demos)]

    @staticmethod
    def log_likelihood(terms, weights, beta: float = 0.0, derivatives: bool = True):
        """Summed L, dL/dw, dL/dbeta over precomputed per-feature terms; None if not ND."""
        total, d_w, d_beta = 0.0, np.zeros(len(weights)), 0.0
        for gs, hs in terms:
            g, hess = weights @ gs, np.tensordot(weights, hs, axes=1)
            lap = laplace_log_likelihood(g, hess, beta=beta, derivatives=derivatives)
            if lap is None:
                return None
            total += lap.value
            if derivatives:
                d_w += gs @ lap.h_vec + np.einsum("ij,kij->k", lap.m_mat, hs)
                d_beta -= np.trace(lap.m_mat)
        return total, d_w, d_beta

    def initial_weights(self) -> np.ndarray:
        rng = np.random.default_rng(self.random_state)
        ks = len(self.features.state_names)
        control = [-1.0 if name.endswith("_effort") else 0.0 for name in self.features.control_names]
        return np.concatenate([0.01 * rng.standard_normal(ks), control])

    def fit(self, demos: Sequence[Demonstration]) -> "LinearCIOC":
        started = time.monotonic()
        terms = self._terms(demos)
        weights0 = self.initial_weights()
        if self.log_likelihood(terms, weights0, 0.0, derivatives=False) is None:
            raise LearningError("the initial reward has no negative definite Hessian")

        def prior(w):
            return -0.5 * self.weight_prior * w @ w, -self.weight_prior * w

        solver = AugmentedLagrangian(lambda w, b: self.log_likelihood(terms, w, b),
                                     outer=self.outer_iterations, max_iter=self.max_iter)
        bounds = [{-1: (None, 0.0), 1: (0.0, None)}.get(self.signs.get(name), (None, None))
                  for name in self.features.names]
        weights0 = np.array([np.clip(w, lo if lo is not None else -np.inf, hi if hi is not None else np.inf)
                             for w, (lo, hi) in zip(weights0, bounds)])
        weights, beta, iterations = solver.run(weights0, 0.0, prior, bounds=bounds)
        final = self.log_likelihood(terms, weights, beta, derivatives=False)
        if final is None or not np.all(np.isfinite(weights)):
            raise LearningError("inverse optimal control diverged")
        if beta > 1e-3:
            LOG.warning("the Hessian needed a regulariser beta=%.3g at the learned weights", beta)
        self.weights_, self.beta_, self.n_iter_ = weights, beta, iterations
        self.log_likelihood_ = final[0] / len(demos)
        self.reward_ = LinearReward(weights, self.features)
        self.fit_time_ = time.monotonic() - started
        return self

    def score(self, demos: Sequence[Demonstration]) -> float:
        """Mean Laplace log-likelihood per demonstration under the learned weights (no regulariser);
        -inf where the Hessian is not negative definite."""
        if not hasattr(self, "weights_"):
            raise NotFittedError("LinearCIOC is not fitted")
        result = self.log_likelihood(self._terms(demos), self.weights_, 0.0, derivatives=False)
        return -np.inf if result is None else result[0] / len(demos)
