"""Rewards over the navigation features: linear, and a Gaussian-process reward (no ROS).

A reward r(x_t, u_t, t) is summed over a trajectory. Both kinds give, per time step, the value and
the derivatives that trajectory optimisation (first order) and inverse optimal control (second
order) need, and both save to and load from plain dicts (YAML/JSON files, database documents).
"""
from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np

from lfd_controller.errors import NotFittedError, RewardFileError
from lfd_controller.features import FeatureSet, FeatureValues, Task
from lfd_controller.hallway_features import HallwayFeatures


@dataclass
class RewardDerivatives:
    """Per-step reward (T,) and derivatives rx (T, 5), ru (T, 2), rxx (T, 5, 5), ruu (T, 2, 2).
    (The features never mix state and action, so d2r/dxdu is zero.)"""

    value: np.ndarray
    rx: np.ndarray
    ru: np.ndarray
    rxx: Optional[np.ndarray] = None
    ruu: Optional[np.ndarray] = None


def compose(fv: FeatureValues, r_phi: np.ndarray, r_phiphi: Optional[np.ndarray], value: np.ndarray,
            control_weights: np.ndarray, order: int) -> RewardDerivatives:
    """Chain per-step derivatives with respect to the state features (T, K) and (T, K, K) through
    the features to the state, and add the linear control cost."""
    rx = np.einsum("tk,tka->ta", r_phi, fv.state_jac)
    ru = np.einsum("c,tca->ta", control_weights, fv.control_jac)
    total = value + fv.control @ control_weights
    if order < 2:
        return RewardDerivatives(total, rx, ru)
    rxx = np.einsum("tk,tkab->tab", r_phi, fv.state_hess)
    if r_phiphi is not None:
        rxx += np.einsum("tka,tkl,tlb->tab", fv.state_jac, r_phiphi, fv.state_jac)
    ruu = np.einsum("c,tcab->tab", control_weights, fv.control_hess)
    return RewardDerivatives(total, rx, ru, rxx, ruu)


class LinearReward:
    """r = w_state . phi(x, t) + w_control . psi(u)."""

    kind = "linear"

    def __init__(self, weights, features: Optional[FeatureSet] = None):
        self.features = features or FeatureSet()
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (len(self.features.names),) or not np.all(np.isfinite(weights)):
            raise RewardFileError(f"a linear reward needs {len(self.features.names)} finite weights "
                                  f"({', '.join(self.features.names)}), got {weights.tolist()}")
        self.weights = weights

    @property
    def state_weights(self) -> np.ndarray:
        return self.weights[:len(self.features.state_names)]

    @property
    def control_weights(self) -> np.ndarray:
        return self.weights[len(self.features.state_names):]

    def derivatives(self, states, actions, times, task: Task, *, order: int = 2) -> RewardDerivatives:
        if order < 2:       # planning: the hand-written first-order path (no jets)
            return RewardDerivatives(*self.features.weighted_first_order(
                states, actions, times, task, self.state_weights, self.control_weights))
        fv = self.features.evaluate(states, actions, times, task, order=order)
        r_phi = np.broadcast_to(self.state_weights, fv.state.shape)
        return compose(fv, r_phi, None, fv.state @ self.state_weights, self.control_weights, order)

    def state_reward(self, states, times, task: Task) -> np.ndarray:
        """The state part of the reward (what the reward-field plots show)."""
        fv = self.features.evaluate(states, np.zeros((len(states), 2)), times, task, order=1)
        return fv.state @ self.state_weights

    def to_dict(self) -> Dict:
        return {"kind": self.kind, "features": self.features.get_params(),
                "weights": {name: float(w) for name, w in zip(self.features.names, self.weights)}}


class GPReward:
    """r = GP posterior mean over the state features + w_control . psi(u) (Levine and Koltun 2012).

    The GP has an ARD squared-exponential kernel k(a, b) = exp(-1/2 sum_d p_d (a_d - b_d)^2) with
    precisions p_d = 1 / lengthscale_d^2, a linear mean w . phi and inducing points Z (state
    features of demonstrated states) with residual rewards y: r(phi) = w . phi + k(phi, Z) alpha,
    alpha = (K_ZZ + noise I)^-1 y.
    """

    kind = "gp"

    def __init__(self, inducing, values, lengthscales, control_weights, *, noise: float = 1e-2,
                 mean_weights=None, features: Optional[FeatureSet] = None):
        self.features = features or FeatureSet()
        self.inducing = np.asarray(inducing, dtype=float)
        self.values = np.asarray(values, dtype=float)
        self.lengthscales = np.asarray(lengthscales, dtype=float)
        self.control_weights = np.asarray(control_weights, dtype=float)
        self.noise = float(noise)
        ks = len(self.features.state_names)
        self.mean_weights = np.zeros(ks) if mean_weights is None else np.asarray(mean_weights, float)
        if (self.inducing.ndim != 2 or self.inducing.shape[1] != ks
                or self.values.shape != (len(self.inducing),) or self.lengthscales.shape != (ks,)
                or self.control_weights.shape != (len(self.features.control_names),)
                or self.mean_weights.shape != (ks,) or not np.all(self.lengthscales > 0)):
            raise RewardFileError(f"GP reward: inducing points (m, {ks}), values (m,), {ks} positive "
                                  f"lengthscales and {len(self.features.control_names)} control "
                                  "weights expected")
        self._alpha = np.linalg.solve(self.gram(), self.values)

    @property
    def precisions(self) -> np.ndarray:
        return self.lengthscales ** -2.0

    def gram(self) -> np.ndarray:
        diff = self.inducing[:, None, :] - self.inducing[None, :, :]
        return np.exp(-0.5 * np.einsum("ijd,d->ij", diff ** 2, self.precisions)) + \
            self.noise * np.eye(len(self.inducing))

    def feature_derivatives(self, phi: np.ndarray, order: int = 2):
        """GP mean at state features phi (T, K), its gradient (T, K) and Hessian (T, K, K)."""
        p = self.precisions
        diff = phi[:, None, :] - self.inducing[None, :, :]
        kv = np.exp(-0.5 * np.einsum("tjd,d->tj", diff ** 2, p)) * self._alpha
        scaled = diff * p
        residual = kv.sum(axis=1)
        grad = -np.einsum("tj,tjd->td", kv, scaled) + self.mean_weights
        hess = None
        if order >= 2:
            hess = np.einsum("tj,tjd,tje->tde", kv, scaled, scaled) - residual[:, None, None] * np.diag(p)
        return residual + phi @ self.mean_weights, grad, hess

    def derivatives(self, states, actions, times, task: Task, *, order: int = 2) -> RewardDerivatives:
        fv = self.features.evaluate(states, actions, times, task, order=order)
        value, grad, hess = self.feature_derivatives(fv.state, order)
        return compose(fv, grad, hess, value, self.control_weights, order)

    def state_reward(self, states, times, task: Task) -> np.ndarray:
        fv = self.features.evaluate(states, np.zeros((len(states), 2)), times, task, order=1)
        return self.feature_derivatives(fv.state, order=1)[0]

    def to_dict(self) -> Dict:
        return {"kind": self.kind, "features": self.features.get_params(), "noise": self.noise,
                "inducing": self.inducing.tolist(), "values": self.values.tolist(),
                "lengthscales": self.lengthscales.tolist(), "mean_weights": self.mean_weights.tolist(),
                "control_weights": self.control_weights.tolist()}


def reward_from_dict(data) -> object:
    """A LinearReward or GPReward from `to_dict` output; RewardFileError when malformed."""
    if not isinstance(data, dict) or data.get("kind") not in ("linear", "gp"):
        raise RewardFileError("a reward needs kind 'linear' or 'gp'")
    try:
        params = dict(data.get("features") or {})
        if params.pop("kind", None) == HallwayFeatures.kind:
            features = HallwayFeatures(**params)
        else:
            features = FeatureSet(**params)
        if data["kind"] == "linear":
            weights = data["weights"]
            missing = [name for name in features.names if name not in weights]
            if missing:
                raise RewardFileError(f"linear reward misses weights for {missing}")
            return LinearReward([weights[name] for name in features.names], features)
        return GPReward(data["inducing"], data["values"], data["lengthscales"],
                        data["control_weights"], noise=data.get("noise", 1e-2),
                        mean_weights=data.get("mean_weights"), features=features)
    except (KeyError, TypeError, ValueError) as err:
        raise RewardFileError(f"malformed {data['kind']} reward: {err!r}") from err


def require_reward(reward):
    if reward is None:
        raise NotFittedError("no reward: learn one (fit) or load one first")
    return reward
