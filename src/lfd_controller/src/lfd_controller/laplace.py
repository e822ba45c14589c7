"""The Laplace-approximated maximum-entropy likelihood of one demonstration (no ROS).

Levine and Koltun (2012): with actions U (T d_u values) of a demonstration and the trajectory
reward R(U) = sum_t r(x_t, u_t) through the dynamics x_t = f(x_{t-1}, u_t), let g = dR/dU and
H = d2R/dU2 at the demonstration. Then

    log P(U) ~ L = 1/2 g^T H^-1 g + 1/2 log|-H| - (T d_u / 2) log 2 pi.

H includes the second-order dynamics term sum_t lambda_t . d2f/dz2 (lambda_t = dR/dx_t, the
adjoint), assembled as in the reduced Hessian of a constrained problem:
H = sum_t Jx_t^T Q_t Jx_t + blocks, Jx_t = dx_t/dU. This module computes g and H for any per-step
reward derivatives, L, and the reverse pass that maps dL/d(g, H) back to dL/d(per-step reward
derivatives), which the GP reward needs.
"""
import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from lfd_controller.errors import DemonstrationError
from lfd_controller.features import Task
from lfd_controller.rewards import RewardDerivatives


class DemoDynamics:
    """Dynamics quantities of one demonstration: states, A_t, B_t, d2f_t and Jx_t = dx_t/dU.

    Args:
        model: a robot_common.unicycle.Unicycle.
        start: x_0 (5,); actions: U (T, 2); t0: episode time of x_0.
    """

    def __init__(self, model, start, actions, t0: float, task: Task):
        actions = np.asarray(actions, dtype=float)
        start = np.asarray(start, dtype=float)
        if actions.ndim != 2 or actions.shape[1] != 2 or len(actions) < 2:
            raise DemonstrationError(f"a demonstration needs actions of shape (T >= 2, 2), "
                                     f"got {actions.shape}")
        if start.shape != (5,) or not np.all(np.isfinite(start)) or not np.all(np.isfinite(actions)):
            raise DemonstrationError("a demonstration needs a finite start state (5,) and finite actions")
        self.task, self.actions, self.start = task, actions, start
        count = len(actions)
        self.T, self.n = count, 2 * count
        self.states = model.rollout(start, actions)
        self.times = t0 + model.dt * np.arange(1, count + 1)
        previous = np.vstack([start, self.states[:-1]])
        _, self.A, self.B, self.F = model.step_derivatives(previous, actions)
        jx = np.zeros((count, 5, self.n))
        for t in range(count):
            if t:
                jx[t] = self.A[t] @ jx[t - 1]
            jx[t, :, 2 * t:2 * t + 2] = self.B[t]
        self.Jx = jx

    def adjoint(self, rx: np.ndarray) -> np.ndarray:
        """lambda_t = dR/dx_t (total, through the future) for per-step rx (T, 5)."""
        lam = np.empty_like(rx)
        lam[-1] = rx[-1]
        for t in range(self.T - 2, -1, -1):
            lam[t] = rx[t] + self.A[t + 1].T @ lam[t + 1]
        return lam

    def grad_hess(self, rd: RewardDerivatives, second_order: bool = True) -> Tuple[np.ndarray, np.ndarray]:
        """g (n,) and H (n, n) of the trajectory reward with respect to the actions
        (second_order False: without the dynamics' second-order term - the Gauss-Newton Hessian
        of iLQR rather than DDP's)."""
        count, n = self.T, self.n
        lam = self.adjoint(rd.rx)
        g = np.einsum("tai,ta->i", self.Jx, rd.rx) + rd.ru.reshape(-1)
        second = np.einsum("ti,tiab->tab", lam, self.F)       # lambda_t . d2f_t (T, 7, 7)
        if not second_order:
            second = np.zeros_like(second)
        q = rd.rxx.copy()
        q[:-1] += second[1:, :5, :5]
        flat = self.Jx.reshape(count * 5, n)
        h = flat.T @ np.einsum("tab,tbj->taj", q, self.Jx).reshape(count * 5, n)
        blocks = h.reshape(count, 2, count, 2)
        idx = np.arange(count)
        blocks[idx, :, idx, :] += rd.ruu + second[:, 5:, 5:]
        cross = np.einsum("tai,tab->ibt", self.Jx[:-1], second[1:, :5, 5:])   # (n, 2, T-1)
        blocks_cross = np.zeros((n, 2, count))
        blocks_cross[:, :, 1:] = cross
        mixed = blocks_cross.transpose(0, 2, 1).reshape(n, n)
        h += mixed + mixed.T
        return g, h

    def backprop(self, h_vec: np.ndarray, m_mat: np.ndarray) -> RewardDerivatives:
        """dL/d(rx, ru, rxx, ruu) from dL/dg = h_vec and dL/dH = m_mat (symmetric)."""
        count = self.T
        jm = (self.Jx.reshape(count * 5, self.n) @ m_mat).reshape(count, 5, self.n)
        d_rxx = np.einsum("taj,tbj->tab", jm, self.Jx)
        m_blocks = m_mat.reshape(count, 2, count, 2)
        idx = np.arange(count)
        d_ruu = m_blocks[idx, :, idx, :]
        # dL/dlambda_t = < d2f_t, Z_t M Z_t^T >, Z_t = [Jx_{t-1}; E_t]
        s = np.zeros((count, 7, 7))
        s[1:, :5, :5] = d_rxx[:-1]
        jm_blocks = jm.reshape(count, 5, count, 2)
        s[1:, :5, 5:] = jm_blocks[idx[:-1], :, idx[1:], :]
        s[:, 5:, :5] = np.swapaxes(s[:, :5, 5:], 1, 2)
        s[:, 5:, 5:] = d_ruu
        nu = np.einsum("tiab,tab->ti", self.F, s)
        mu = np.empty_like(nu)
        mu[0] = nu[0]
        for t in range(1, count):
            mu[t] = self.A[t] @ mu[t - 1] + nu[t]
        d_rx = np.einsum("tai,i->ta", self.Jx, h_vec) + mu
        return RewardDerivatives(np.zeros(count), d_rx, h_vec.reshape(count, 2), d_rxx, d_ruu)


@dataclass
class LaplaceTerms:
    """L, and its derivatives dL/dg (h_vec) and dL/dH (m_mat) when requested."""

    value: float
    h_vec: Optional[np.ndarray] = None
    m_mat: Optional[np.ndarray] = None


def laplace_log_likelihood(g: np.ndarray, hess: np.ndarray, *, beta: float = 0.0,
                           derivatives: bool = True) -> Optional[LaplaceTerms]:
    """L for H - beta I; None when H - beta I is not negative definite (no Laplace approximation)."""
    n = len(g)
    try:
        chol = np.linalg.cholesky(-(hess - beta * np.eye(n)))
    except np.linalg.LinAlgError:
        return None
    z = np.linalg.solve(chol, g)
    value = -0.5 * z @ z + np.sum(np.log(np.diag(chol))) - 0.5 * n * math.log(2.0 * math.pi)
    if not derivatives:
        return LaplaceTerms(float(value))
    inv_chol = np.linalg.solve(chol, np.eye(n))
    neg_inv = inv_chol.T @ inv_chol        # (-H)^-1
    h_vec = -(inv_chol.T @ z)              # H^-1 g
    m_mat = 0.5 * (-neg_inv - np.outer(h_vec, h_vec))
    return LaplaceTerms(float(value), h_vec, m_mat)


@dataclass
class NoisyLaplaceTerms(LaplaceTerms):
    """LaplaceTerms plus dL/d(noise variances) per action entry (n,)."""

    noise_grad: Optional[np.ndarray] = None


def noisy_laplace_log_likelihood(g: np.ndarray, hess: np.ndarray, noise: np.ndarray, *,
                                 beta: float = 0.0,
                                 derivatives: bool = True) -> Optional[NoisyLaplaceTerms]:
    """The Laplace likelihood with action noise: the demonstrated commands are the locally optimal
    ones plus independent Gaussian noise of variances `noise` (n,) (a quantised stick, a shaking
    hand), so U_demo ~ N(U*, A^-1 + S), A = -(H - beta I), U* = U_demo + A^-1 g, S = diag(noise):

        L = -1/2 g^T B^-1 g - 1/2 log|B| + log|A| - (n/2) log 2 pi,   B = A + A S A,

    which is L of laplace_log_likelihood for S = 0. Returns dL/dg (h_vec), dL/dH (m_mat) and
    dL/dnoise; None when H - beta I is not negative definite."""
    n = len(g)
    a_mat = -(hess - beta * np.eye(n))
    try:
        chol_a = np.linalg.cholesky(a_mat)
        b_mat = a_mat + (a_mat * noise[None, :]) @ a_mat
        chol_b = np.linalg.cholesky(b_mat)
    except np.linalg.LinAlgError:
        return None
    z = np.linalg.solve(chol_b, g)
    value = (-0.5 * z @ z - np.sum(np.log(np.diag(chol_b))) + 2.0 * np.sum(np.log(np.diag(chol_a)))
             - 0.5 * n * math.log(2.0 * math.pi))
    if not derivatives:
        return NoisyLaplaceTerms(float(value))
    inv_chol_b = np.linalg.solve(chol_b, np.eye(n))
    b_inv = inv_chol_b.T @ inv_chol_b
    inv_chol_a = np.linalg.solve(chol_a, np.eye(n))
    a_inv = inv_chol_a.T @ inv_chol_a
    h = inv_chol_b.T @ z                                    # B^-1 g
    n_mat = 0.5 * (np.outer(h, h) - b_inv)                   # dL/dB
    an = a_mat @ n_mat
    cross = noise[:, None] * an                              # S A N
    d_a = n_mat + cross + cross.T + a_inv                    # dL/dA
    noise_grad = np.einsum("ij,ji->i", an, a_mat)            # diag(A N A)
    return NoisyLaplaceTerms(float(value), -h, -d_a, noise_grad)
