"""Behaviour cloning: the simple baseline trained on the same demonstrations (no ROS).

A multilayer perceptron regresses the demonstrated command on what the robot sees: the goal and
the obstacle in the robot's frame, the obstacle's velocity in that frame, and the robot's speeds.
"""
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

    def __init__(self, hidden=(64, 64), max_iter: int = 3000, random_state=None):
        self.hidden, self.max_iter, self.random_state = hidden, max_iter, random_state

    def fit(self, demos) -> "BehaviourCloning":
        inputs, targets = [], []
        for demo in demos:
            task = Task.from_scenario(demo.scenario)
            states, times = demo.trajectory(), demo.times()
            for k, action in enumerate(demo.actions):
                inputs.append(observation(states[k], times[k], task, demo.scenario.dt))
                targets.append(action)
        network = MLPRegressor(hidden_layer_sizes=self.hidden, max_iter=self.max_iter,
                               random_state=self.random_state)
        self.model_ = make_pipeline(StandardScaler(), network).fit(inputs, targets)
        return self

    def predict(self, state, t: float, task) -> np.ndarray:
        if not hasattr(self, "model_"):
            raise NotFittedError("BehaviourCloning is not fitted")
        return self.model_.predict(observation(state, t, task)[None])[0]
