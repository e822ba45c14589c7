"""Continuous inverse optimal control with a Gaussian-process reward (Levine and Koltun 2012; no ROS).

The reward's state part is the posterior mean of a GP over the state features with inducing points
Z (features of demonstrated states), an ARD squared-exponential kernel and a linear mean function,
    r(phi) = w . phi + k(phi, Z) alpha,  alpha = (K_ZZ + noise I)^-1 y,
plus the linear control cost w_c . psi(u). (The paper's GP has zero mean; the linear mean, started
at the linear CIOC solution, starts the search where H is negative definite and lets the GP model
what the linear reward cannot.) The learned quantities are the inducing rewards y, the log
precisions (ARD), w and w_c; the objective is the summed Laplace log-likelihood of the
demonstrations plus the GP prior log N(y; 0, K_ZZ + noise I) and a weak log-normal prior on the
lengthscales. Gradients are analytic: laplace.py maps dL/d(g, H) back to dL/d(per-step reward
derivatives), which are chained here through the features and the kernel (including alpha's
dependence on the precisions). The regulariser beta of H - beta I is driven to zero by the same
augmented Lagrangian as the linear learner.
"""
import time
from typing import Optional, Sequence

import numpy as np

from lfd_controller.cioc import AugmentedLagrangian, LinearCIOC, prepare
from lfd_controller.demos import Demonstration
from lfd_controller.errors import LearningError, NotFittedError
from lfd_controller.features import FeatureSet
from lfd_controller.laplace import laplace_log_likelihood
from lfd_controller.rewards import GPReward, compose


class GPCIOC:
    """Learns a GP reward (sklearn-style).

    Args:
        features: the FeatureSet; max_inducing: number of inducing points (demo states, evenly
        subsampled); noise: the GP's jitter/noise on K_ZZ; lengthscale_prior_std: std of the
        log-lengthscale prior around the features' spread; outer_iterations, max_iter: augmented
        Lagrangian rounds and L-BFGS iterations; random_state: reproducibility.
    Fitted attributes: reward_ (GPReward), linear_ (the LinearCIOC used to initialise), beta_,
    log_likelihood_ (per demonstration), n_iter_, fit_time_.
    """

    def __init__(self, features: Optional[FeatureSet] = None, *, max_inducing: int = 60,
                 noise: float = 1e-2, lengthscale_prior_std: float = 1.0, outer_iterations: int = 4,
                 max_iter: int = 150, random_state=None):
        self.features = features or FeatureSet()
        self.max_inducing, self.noise = max_inducing, noise
        self.lengthscale_prior_std = lengthscale_prior_std
        self.outer_iterations, self.max_iter = outer_iterations, max_iter
        self.random_state = random_state

    def _setup(self, demos):
        self._dyns = prepare(demos)
        self._fvs = [self.features.evaluate(d.states, d.actions, d.times, d.task) for d in self._dyns]
        phis = np.vstack([fv.state for fv in self._fvs])
        rng = np.random.default_rng(self.random_state)
        count = min(self.max_inducing, len(phis))
        self.inducing_ = phis[np.sort(rng.choice(len(phis), count, replace=False))]
        self._log_scale0 = np.log(np.maximum(phis.std(axis=0), 1e-2))
        ks = phis.shape[1]
        self._sizes = (count, ks, len(self.features.control_names))

    def _split(self, params):
        m, ks, kc = self._sizes
        return (params[:m], np.exp(params[m:m + ks]), params[m + ks:m + ks + kc],
                params[m + ks + kc:])

    def objective(self, params, beta: float):
        """(sum of L + priors, gradient, dL/dbeta), or None when some H - beta I is not ND."""
        values, precisions, control_w, mean_w = self._split(params)
        if not np.all(np.isfinite(precisions)):
            return None
        diff_z = self.inducing_[:, None, :] - self.inducing_[None, :, :]
        kernel = np.exp(-0.5 * np.einsum("ijd,d->ij", diff_z ** 2, precisions))
        gram = kernel + self.noise * np.eye(len(values))
        chol = np.linalg.cholesky(gram)
        alpha = np.linalg.solve(gram, values)
        total, d_alpha, d_prec = 0.0, np.zeros_like(values), np.zeros_like(precisions)
        d_control, d_beta, d_mean = np.zeros_like(control_w), 0.0, np.zeros_like(mean_w)
        for dyn, fv in zip(self._dyns, self._fvs):
            diff = fv.state[:, None, :] - self.inducing_[None, :, :]          # (T, m, K)
            kv = np.exp(-0.5 * np.einsum("tjd,d->tj", diff ** 2, precisions))
            scaled = diff * precisions
            weighted = kv * alpha
            value = weighted.sum(axis=1) + fv.state @ mean_w
            r_phi = -np.einsum("tj,tjd->td", weighted, scaled) + mean_w
            r_phiphi = (np.einsum("tj,tjd,tje->tde", weighted, scaled, scaled)
                        - weighted.sum(axis=1)[:, None, None] * np.diag(precisions))
            rd = compose(fv, r_phi, r_phiphi, value, control_w, 2)
            g, hess = dyn.grad_hess(rd)
            lap = laplace_log_likelihood(g, hess, beta=beta)
            if lap is None:
                return None
            total += lap.value
            d_beta -= np.trace(lap.m_mat)
            back = dyn.backprop(lap.h_vec, lap.m_mat)
            a = (np.einsum("tka,ta->tk", fv.state_jac, back.rx)
                 + np.einsum("tkab,tab->tk", fv.state_hess, back.rxx))
            b = np.einsum("tka,tab,tlb->tkl", fv.state_jac, back.rxx, fv.state_jac)
            d_mean += a.sum(axis=0)
            d_control += (np.einsum("tca,ta->c", fv.control_jac, back.ru)
                          + np.einsum("tcab,tab->c", fv.control_hess, back.ruu))
            bs = np.einsum("tde,tje->tjd", b, scaled)
            bracket = (-np.einsum("td,tjd->tj", a, scaled) + np.einsum("tjd,tjd->tj", scaled, bs)
                       - np.einsum("tdd,d->t", b, precisions)[:, None])
            d_alpha += np.einsum("tj,tj->j", kv, bracket)
            diag_b = np.einsum("tdd->td", b)
            d_prec += np.einsum("tj,tjd->d", weighted,
                                -0.5 * diff ** 2 * bracket[:, :, None] - a[:, None, :] * diff
                                + 2.0 * diff * bs - diag_b[:, None, :])
        # alpha = gram^-1 y: chain to y and (through gram) to the precisions
        back_alpha = np.linalg.solve(gram, d_alpha)
        d_kernel = -0.5 * diff_z ** 2 * kernel[:, :, None]                  # dK/dp_d (m, m, K)
        d_prec += -np.einsum("i,ijd,j->d", back_alpha, d_kernel, alpha)
        d_values = back_alpha
        # GP prior log N(y; 0, s2 gram), s2 fixed from the linear reward's spread
        signal, m = self.signal_, len(values)
        total += -0.5 * values @ alpha / signal - np.sum(np.log(np.diag(chol))) - 0.5 * m * np.log(signal)
        d_values = d_values - alpha / signal
        gram_inv = np.linalg.solve(gram, np.eye(m))
        d_prec += 0.5 * np.einsum("i,ijd,j->d", alpha, d_kernel, alpha) / signal \
            - 0.5 * np.einsum("ij,jid->d", gram_inv, d_kernel)
        # log-normal prior on the lengthscales (log lengthscale = -log(p) / 2)
        log_scale = -0.5 * np.log(precisions)
        offset = (log_scale - self._log_scale0) / self.lengthscale_prior_std ** 2
        total += -0.5 * np.sum(offset * (log_scale - self._log_scale0))
        d_log_prec = d_prec * precisions + 0.5 * offset
        return total, np.concatenate([d_values, d_log_prec, d_control, d_mean]), d_beta

    def initial_params(self, demos) -> np.ndarray:
        """Start at the linear CIOC solution: its weights as the GP's mean function, zero residual."""
        self.linear_ = LinearCIOC(self.features, random_state=self.random_state).fit(demos)
        linear = self.linear_.reward_
        spread = np.vstack([fv.state for fv in self._fvs]) @ linear.state_weights
        self.signal_ = max((0.25 * spread.std()) ** 2, 1e-6)
        return np.concatenate([np.zeros(self._sizes[0]), -2.0 * self._log_scale0,
                               linear.control_weights, linear.state_weights])

    def fit(self, demos: Sequence[Demonstration]) -> "GPCIOC":
        started = time.monotonic()
        self._setup(demos)
        params0 = self.initial_params(demos)
        beta0 = 0.0
        while self.objective(params0, beta0) is None:
            beta0 = max(1.0, 10.0 * beta0)
            if beta0 > 1e6:
                raise LearningError("no regulariser makes the GP reward's Hessian negative definite")
        solver = AugmentedLagrangian(self.objective, outer=self.outer_iterations, max_iter=self.max_iter)
        m, ks, kc = self._sizes
        # log precisions within 4 orders of magnitude of the features' spread
        centre = -2.0 * self._log_scale0
        bounds = [(None, None)] * m + [(c - 9.2, c + 9.2) for c in centre] + [(None, None)] * (kc + ks)
        params, beta, iterations = solver.run(params0, beta0, bounds=bounds)
        final = self.objective(params, beta)
        if final is None or not np.all(np.isfinite(params)):
            raise LearningError("GP inverse optimal control diverged")
        values, precisions, control_w, mean_w = self._split(params)
        self.reward_ = GPReward(self.inducing_, values, precisions ** -0.5, control_w, noise=self.noise,
                                mean_weights=mean_w, features=self.features)
        self.beta_, self.n_iter_ = beta, iterations
        self.log_likelihood_ = final[0] / len(demos)
        self.fit_time_ = time.monotonic() - started
        return self

    def predict(self, states, times, task) -> np.ndarray:
        """The learned state reward at states (N, 5) and times (N,)."""
        if not hasattr(self, "reward_"):
            raise NotFittedError("GPCIOC is not fitted")
        return self.reward_.state_reward(states, times, task)
