"""Behaviour cloning: the baseline trained on the same demonstrations (no ROS).

A multilayer perceptron regresses the demonstrated command on what the robot sees: the goal and
the obstacle in the robot's frame, the obstacle's velocity in that frame, and the robot's speeds.
`tune_behaviour_cloning` chooses its size and regularisation (and several initialisations) on
validation drives, as carefully as the learner's settings are chosen; data from drives with noise
injected into the executed commands (DART, Laskey et al. 2017) are built by the demonstrators
module (demonstrators.dart_demos).
"""
from typing import Callable, Optional, Sequence

import numpy as np
from sklearn.neural_network import MLPRegressor
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from lfd_controller.errors import NotFittedError
from lfd_controller.features import Task


def observation(state, t: float, task, dt: float = 0.1) -> np.ndarray:
    px, py, yaw, v, w = state
    cos, sin = np.cos(yaw), np.sin(yaw)

    def local(dx, dy):
        return [cos * dx + sin * dy, -sin * dx + cos * dy]
    goal = local(task.goal[0] - px, task.goal[1] - py)
    obstacle_now = np.asarray(task.obstacle_position(np.array(t)), float)
    obstacle_next = np.asarray(task.obstacle_position(np.array(t + dt)), float)
    obstacle = local(obstacle_now[0] - px, obstacle_now[1] - py)
    velocity = local(*((obstacle_next - obstacle_now) / dt))
    return np.array(goal + obstacle + velocity + [v, w])


class BehaviourCloning:
    """sklearn-style policy: fit(demos) then predict(state, t, task) -> command."""

    def __init__(self, hidden=(64, 64), max_iter: int = 3000, random_state=None, alpha: float = 1e-4):
        self.hidden, self.max_iter, self.random_state = hidden, max_iter, random_state
        self.alpha = alpha

    def fit(self, demos) -> "BehaviourCloning":
        inputs, targets = [], []
        for demo in demos:       # a demonstration with its own task (a hallway window) uses it
            task = getattr(demo, "task", None) or Task.from_scenario(demo.scenario)
            states, times = demo.trajectory(), demo.times()
            for k, action in enumerate(demo.actions):
                inputs.append(observation(states[k], times[k], task, demo.scenario.dt))
                targets.append(action)
        network = MLPRegressor(hidden_layer_sizes=self.hidden, max_iter=self.max_iter,
                               random_state=self.random_state, alpha=self.alpha)
        self.model_ = make_pipeline(StandardScaler(), network).fit(inputs, targets)
        return self

    def predict(self, state, t: float, task) -> np.ndarray:
        if not hasattr(self, "model_"):
            raise NotFittedError("BehaviourCloning is not fitted")
        return self.model_.predict(observation(state, t, task)[None])[0]

    def get_params(self) -> dict:
        return {"hidden": tuple(self.hidden), "alpha": self.alpha, "random_state": self.random_state}


BC_GRID = {"hidden": ((32,), (64, 64), (128, 128)), "alpha": (1e-4, 1e-2, 1.0)}


def tune_behaviour_cloning(demos, validate: Callable[[BehaviourCloning], float], *,
                           grid: Optional[dict] = None, seeds: Sequence[int] = (0, 1, 2),
                           max_iter: int = 2000):
    """The BehaviourCloning (fitted on `demos`) with the best validate(policy) score (higher is
    better: e.g. closed-loop success on validation starts, never the test starts) over the grid of
    sizes and L2 regularisation and several initialisations; returns (policy, table of scores)."""
    grid = grid or BC_GRID
    best, table = None, []
    for hidden in grid["hidden"]:
        for alpha in grid["alpha"]:
            for seed in seeds:
                policy = BehaviourCloning(hidden, max_iter, seed, alpha).fit(demos)
                score = float(validate(policy))
                table.append({"hidden": list(hidden), "alpha": alpha, "seed": seed, "score": score})
                if best is None or score > best[0]:
                    best = (score, policy)
    return best[1], table
