"""A turtlebot-like unicycle with velocity and acceleration limits, and its derivatives (no ROS).

This module is the one source of the robot's dynamics: the simulator node steps it, and the
learning code (inverse optimal control, trajectory optimisation, controller) differentiates it.

State  x = (px, py, yaw, v, w): position (m), heading (rad), linear (m/s) and angular (rad/s) speed.
Action u = (v_cmd, w_cmd): the commanded speeds, as carried by cmd_vel.

One step of length dt:
    v' = v + S_a(S_v(v_cmd) - v)        w' = w + S_b(S_w(w_cmd) - w)
    yaw' = yaw + dt w'   px' = px + dt v' cos(yaw')   py' = py + dt v' sin(yaw')
where S_c(z) = z / (1 + (z/c)^4)^(1/4) is a smooth saturation at +-c (identity for |z| << c):
S_v, S_w limit the commanded speeds to v_max, w_max, S_a, S_b limit the speed change per step to
a_max dt and alpha_max dt. Smooth limits keep first and second derivatives defined everywhere,
which inverse optimal control needs (its Hessian includes the dynamics' second derivatives).
"""
import math
from dataclasses import dataclass
from typing import Tuple

import numpy as np

from robot_common.errors import ModelError

STATE_DIM = 5
ACTION_DIM = 2
PX, PY, YAW, V, W = range(5)
# Indices of the joint input z = (state, action) used by step_derivatives.
U_V, U_W = 5, 6


def saturate(z, limit: float):
    """Smooth saturation S(z) = z / (1 + (z/limit)^4)^(1/4) and its first two derivatives."""
    s = np.asarray(z, dtype=float) / limit
    base = 1.0 + s ** 4
    value = limit * s * base ** -0.25
    first = base ** -1.25
    second = -5.0 * s ** 3 * base ** -2.25 / limit
    return value, first, second


def _sat(z: float, limit: float) -> float:
    s = z / limit
    return z / math.sqrt(math.sqrt(1.0 + s * s * s * s))


def _sat_slope(z: float, limit: float) -> Tuple[float, float]:
    """S(z) and S'(z) for one float (`saturate` without numpy, for scalar loops)."""
    s = z / limit
    base = 1.0 + s * s * s * s
    root = math.sqrt(math.sqrt(base))
    return z / root, 1.0 / (base * root)


def saturate_inverse(y, limit: float):
    """The z with S(z) = y, for |y| < limit (raises ModelError outside)."""
    s = np.asarray(y, dtype=float) / limit
    if np.any(np.abs(s) >= 1.0):
        raise ModelError(f"cannot invert saturation at {limit} for values {np.max(np.abs(y))}")
    return limit * s * (1.0 - s ** 4) ** -0.25


@dataclass(frozen=True)
class UnicycleLimits:
    """Speed and acceleration limits of the robot (defaults: a TurtleBot 2-like base)."""

    v_max: float = 0.6
    w_max: float = 2.0
    a_max: float = 1.0
    alpha_max: float = 4.0

    def __post_init__(self):
        for name in ("v_max", "w_max", "a_max", "alpha_max"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ModelError(f"unicycle limit {name} must be a positive number, got {value!r}")


class Unicycle:
    """Discrete-time unicycle x' = f(x, u) with smooth limits, vectorised over leading axes."""

    def __init__(self, dt: float = 0.1, limits: UnicycleLimits = UnicycleLimits()):
        if not np.isfinite(dt) or dt <= 0:
            raise ModelError(f"time step dt must be positive, got {dt!r}")
        self.dt = float(dt)
        self.limits = limits

    def _speed_update(self, speed, command, limit, step_limit):
        """new speed, d/dspeed, d/dcommand and the three second derivatives."""
        cmd, cmd_d1, cmd_d2 = saturate(command, limit)
        change, ch_d1, ch_d2 = saturate(cmd - speed, step_limit)
        new = speed + change
        d_speed = 1.0 - ch_d1
        d_cmd = ch_d1 * cmd_d1
        dd_speed = ch_d2
        dd_cross = -ch_d2 * cmd_d1
        dd_cmd = ch_d2 * cmd_d1 ** 2 + ch_d1 * cmd_d2
        return new, (d_speed, d_cmd), (dd_speed, dd_cross, dd_cmd)

    def step(self, state, action) -> np.ndarray:
        """The next state(s); state (..., 5), action (..., 2)."""
        state, action = self._check(state, action)
        lim, dt = self.limits, self.dt
        v_new = self._speed_update(state[..., V], action[..., 0], lim.v_max, lim.a_max * dt)[0]
        w_new = self._speed_update(state[..., W], action[..., 1], lim.w_max, lim.alpha_max * dt)[0]
        yaw = state[..., YAW] + dt * w_new
        return np.stack([state[..., PX] + dt * v_new * np.cos(yaw),
                         state[..., PY] + dt * v_new * np.sin(yaw), yaw, v_new, w_new], axis=-1)

    def rollout(self, state0, actions) -> np.ndarray:
        """States x_1..x_T (T, 5) reached from x_0 by actions (T, 2) (a fast scalar loop)."""
        actions = np.asarray(actions, dtype=float)
        if actions.ndim != 2 or actions.shape[1] != ACTION_DIM:
            raise ModelError(f"actions must have shape (T, 2), got {actions.shape}")
        state0, _ = self._check(state0, actions)
        lim, dt = self.limits, self.dt
        a_step, b_step = lim.a_max * dt, lim.alpha_max * dt
        px, py, yaw, v, w = (float(value) for value in state0)
        out = []
        for v_cmd, w_cmd in actions.tolist():
            v += _sat(_sat(v_cmd, lim.v_max) - v, a_step)
            w += _sat(_sat(w_cmd, lim.w_max) - w, b_step)
            yaw += dt * w
            px += dt * v * math.cos(yaw)
            py += dt * v * math.sin(yaw)
            out.append((px, py, yaw, v, w))
        return np.array(out).reshape(-1, STATE_DIM)

    def rollout_partials(self, state0, actions):
        """`rollout` and, per step, the nonzero first derivatives of the step: (cos yaw', sin yaw',
        v', dv'/dv, dv'/dv_cmd, dw'/dw, dw'/dw_cmd), for `rollout_adjoint`. A scalar loop: for a
        planning horizon of tens of steps far cheaper than step_derivatives (tested against it)."""
        actions = np.asarray(actions, dtype=float)
        state0, _ = self._check(state0, actions)
        lim, dt = self.limits, self.dt
        a_step, b_step = lim.a_max * dt, lim.alpha_max * dt
        px, py, yaw, v, w = (float(value) for value in state0)
        states, partials = [], []
        for v_cmd, w_cmd in actions.reshape(-1, ACTION_DIM).tolist():
            v_sat, v_sat_d = _sat_slope(v_cmd, lim.v_max)
            v_change, v_change_d = _sat_slope(v_sat - v, a_step)
            w_sat, w_sat_d = _sat_slope(w_cmd, lim.w_max)
            w_change, w_change_d = _sat_slope(w_sat - w, b_step)
            v += v_change
            w += w_change
            yaw += dt * w
            cos, sin = math.cos(yaw), math.sin(yaw)
            px += dt * v * cos
            py += dt * v * sin
            states.append((px, py, yaw, v, w))
            partials.append((cos, sin, v, 1.0 - v_change_d, v_change_d * v_sat_d,
                             1.0 - w_change_d, w_change_d * w_sat_d))
        return np.array(states).reshape(-1, STATE_DIM), partials

    def step_derivatives(self, state, action, *, second: bool = True
                         ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Next state and its derivatives with respect to z = (x, u), batched over axis 0.

        Returns (next (N, 5), A = dx'/dx (N, 5, 5), B = dx'/du (N, 5, 2),
        F = d2x'/dz2 (N, 5, 7, 7) or None when second is False).
        """
        state, action = self._check(np.atleast_2d(state), np.atleast_2d(action))
        lim, dt = self.limits, self.dt
        n = state.shape[0]
        v_new, v_d, v_dd = self._speed_update(state[:, V], action[:, 0], lim.v_max, lim.a_max * dt)
        w_new, w_d, w_dd = self._speed_update(state[:, W], action[:, 1], lim.w_max,
                                              lim.alpha_max * dt)
        yaw = state[:, YAW] + dt * w_new
        cos, sin = np.cos(yaw), np.sin(yaw)
        grad_v = np.zeros((n, 7))
        grad_v[:, V], grad_v[:, U_V] = v_d
        grad_w = np.zeros((n, 7))
        grad_w[:, W], grad_w[:, U_W] = w_d
        grad_yaw = dt * grad_w
        grad_yaw[:, YAW] += 1.0
        jac = np.zeros((n, 5, 7))
        jac[:, PX] = dt * (cos[:, None] * grad_v - (v_new * sin)[:, None] * grad_yaw)
        jac[:, PY] = dt * (sin[:, None] * grad_v + (v_new * cos)[:, None] * grad_yaw)
        jac[:, PX, PX] += 1.0
        jac[:, PY, PY] += 1.0
        jac[:, YAW], jac[:, V], jac[:, W] = grad_yaw, grad_v, grad_w
        next_state = np.stack([state[:, PX] + dt * v_new * cos, state[:, PY] + dt * v_new * sin,
                               yaw, v_new, w_new], axis=-1)
        hess = None
        if second:
            hess = self._second_derivatives(v_new, cos, sin, grad_v, grad_yaw, v_dd, w_dd)
        return next_state, jac[:, :, :5], jac[:, :, 5:], hess

    def _second_derivatives(self, v_new, cos, sin, grad_v, grad_yaw, v_dd, w_dd) -> np.ndarray:
        n, dt = len(v_new), self.dt
        hess_v = np.zeros((n, 7, 7))
        hess_v[:, V, V], hess_v[:, V, U_V], hess_v[:, U_V, U_V] = v_dd
        hess_v[:, U_V, V] = hess_v[:, V, U_V]
        hess_w = np.zeros((n, 7, 7))
        hess_w[:, W, W], hess_w[:, W, U_W], hess_w[:, U_W, U_W] = w_dd
        hess_w[:, U_W, W] = hess_w[:, W, U_W]
        hess_yaw = dt * hess_w
        outer_vy = grad_v[:, :, None] * grad_yaw[:, None, :]
        sym_vy = outer_vy + np.swapaxes(outer_vy, 1, 2)
        outer_yy = grad_yaw[:, :, None] * grad_yaw[:, None, :]
        c, s, v = cos[:, None, None], sin[:, None, None], v_new[:, None, None]
        hess = np.zeros((n, 5, 7, 7))
        hess[:, PX] = dt * (c * hess_v - s * sym_vy - v * c * outer_yy - v * s * hess_yaw)
        hess[:, PY] = dt * (s * hess_v + c * sym_vy - v * s * outer_yy + v * c * hess_yaw)
        hess[:, YAW], hess[:, V], hess[:, W] = hess_yaw, hess_v, hess_w
        return hess

    def command_for_speeds(self, state, v_target: float, w_target: float) -> np.ndarray:
        """The command that reaches the target speeds in one step (if reachable; else clipped)."""
        lim, dt = self.limits, self.dt
        out = []
        for speed, target, limit, step in ((state[V], v_target, lim.v_max, lim.a_max * dt),
                                           (state[W], w_target, lim.w_max, lim.alpha_max * dt)):
            change = np.clip(target - speed, -0.98 * step, 0.98 * step)
            wanted = np.clip(speed + float(saturate_inverse(change, step)), -0.98 * limit,
                             0.98 * limit)
            out.append(float(saturate_inverse(wanted, limit)))
        return np.array(out)

    def _check(self, state, action):
        state = np.asarray(state, dtype=float)
        action = np.asarray(action, dtype=float)
        if state.shape[-1] != STATE_DIM or action.shape[-1] != ACTION_DIM:
            raise ModelError(f"state must end in 5 values and action in 2, got shapes "
                           f"{state.shape} and {action.shape}")
        if not (np.all(np.isfinite(state)) and np.all(np.isfinite(action))):
            raise ModelError("state and action must be finite numbers")
        return state, action


def rollout_adjoint(dt: float, partials, rx, ru) -> np.ndarray:
    """dR/dU (T, 2) of R = sum_t r(x_t, u_t) by the adjoint pass over the sparse step Jacobians
    that `Unicycle.rollout_partials` returns: lambda_t = r_x,t + A_{t+1}^T lambda_{t+1},
    g_t = r_u,t + B_t^T lambda_t (rx (T, 5), ru (T, 2): the reward's derivatives per step)."""
    count = len(partials)
    grad = np.asarray(ru, float).tolist()
    rx = np.asarray(rx, float).tolist()
    lx = ly = lyaw = lv = lw = 0.0            # A_{t+1}^T lambda_{t+1} (0 after the last step)
    for t in range(count - 1, -1, -1):
        lx, ly, lyaw, lv, lw = (lx + rx[t][0], ly + rx[t][1], lyaw + rx[t][2], lv + rx[t][3],
                                lw + rx[t][4])
        cos, sin, v, v_v, v_cmd, w_w, w_cmd = partials[t]
        # sensitivities to this step's new yaw, v, w through the position update
        q_yaw = lyaw + dt * v * (ly * cos - lx * sin)
        q_v = lv + dt * (lx * cos + ly * sin)
        q_w = lw + dt * q_yaw
        grad[t][0] += q_v * v_cmd
        grad[t][1] += q_w * w_cmd
        lyaw, lv, lw = q_yaw, q_v * v_v, q_w * w_w     # A_t^T lambda_t (px, py pass through)
    return np.array(grad)
