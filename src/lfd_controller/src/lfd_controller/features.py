"""Smooth reward features for navigating to a goal around one (possibly moving) obstacle (no ROS).

The original features were the radial vectors from the robot to the goal and to the obstacle and
the angle between them. They are made smooth (softened norms, Gaussian fall-offs) so the reward
has the first and second derivatives inverse optimal control needs; exact derivatives come from
forward-mode automatic differentiation (jets.py). State features depend on (px, py, yaw) and on
the episode time through the obstacle's position; control features are the squared commands.
"""
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence

import numpy as np

from lfd_controller.errors import LfdError
from lfd_controller.jets import Jet

STATE_FEATURES = ("goal_distance", "goal_heading", "obstacle_proximity", "obstacle_ahead")
CONTROL_FEATURES = ("speed_effort", "turn_effort")
FEATURE_NAMES = STATE_FEATURES + CONTROL_FEATURES


@dataclass
class Task:
    """Where to go and where the obstacle is at episode time t (positions (..., 2))."""

    goal: np.ndarray
    obstacle_position: Callable[[np.ndarray], np.ndarray]
    obstacle_radius: float = 0.25

    @classmethod
    def from_scenario(cls, scenario) -> "Task":
        return cls(np.asarray(scenario.goal, float), scenario.obstacle.position,
                   scenario.obstacle.radius)

    @classmethod
    def constant_velocity(cls, goal, position, velocity, now: float,
                          radius: float = 0.25) -> "Task":
        """An obstacle seen at `position` moving at `velocity` at episode time `now`."""
        position, velocity = np.asarray(position, float), np.asarray(velocity, float)

        def predict(t):
            return position + (np.asarray(t, float)[..., None] - now) * velocity
        return cls(np.asarray(goal, float), predict, radius)


@dataclass
class FeatureValues:
    """Features along a trajectory: state features (T, Ks) with jac (T, Ks, 5) and hess
    (T, Ks, 5, 5); control features (T, Kc) with jac (T, Kc, 2) and hess (T, Kc, 2, 2)."""

    state: np.ndarray
    state_jac: np.ndarray
    state_hess: Optional[np.ndarray]
    control: np.ndarray
    control_jac: np.ndarray
    control_hess: np.ndarray


class FeatureSet:
    """The reward features and their derivatives along trajectories.

    Args:
        goal_softening: softening length of the goal distance (m).
        heading_softening: softening length of the goal heading's normalisation (m).
        proximity_scale: Gaussian fall-off length of the obstacle proximity (m).
        ahead_scale: fall-off length of the "obstacle between me and the goal" feature (m).
    """

    names: Sequence[str] = FEATURE_NAMES
    state_names: Sequence[str] = STATE_FEATURES
    control_names: Sequence[str] = CONTROL_FEATURES

    def __init__(self, *, goal_softening: float = 0.2, heading_softening: float = 0.3,
                 proximity_scale: float = 0.35, ahead_scale: float = 0.8):
        for name, value in (("goal_softening", goal_softening), ("heading_softening", heading_softening),
                            ("proximity_scale", proximity_scale), ("ahead_scale", ahead_scale)):
            if not value > 0:
                raise LfdError(f"feature parameter {name} must be positive, got {value!r}")
        self.goal_softening = goal_softening
        self.heading_softening = heading_softening
        self.proximity_scale = proximity_scale
        self.ahead_scale = ahead_scale

    def get_params(self) -> dict:
        return {"goal_softening": self.goal_softening, "heading_softening": self.heading_softening,
                "proximity_scale": self.proximity_scale, "ahead_scale": self.ahead_scale}

    def _state_jets(self, states: np.ndarray, goal: np.ndarray, obstacles: np.ndarray) -> List[Jet]:
        px, py, yaw = Jet.variables(states[:, :3])
        gx, gy = goal[0] - px, goal[1] - py            # radial vector to the goal
        ox, oy = obstacles[:, 0] - px, obstacles[:, 1] - py   # radial vector to the obstacle
        goal_sq = gx.square() + gy.square()
        obst_sq = ox.square() + oy.square()
        soft = self.goal_softening
        goal_distance = (goal_sq + soft ** 2).sqrt() - soft
        heading = (gx * yaw.cos() + gy * yaw.sin()) / (goal_sq + self.heading_softening ** 2).sqrt()
        proximity = (obst_sq * (-0.5 / self.proximity_scale ** 2)).exp()
        cos_between = (gx * ox + gy * oy) / ((goal_sq + 0.01) * (obst_sq + 0.01)).sqrt()
        ahead = (obst_sq * (-0.5 / self.ahead_scale ** 2)).exp() * (cos_between + 1.0) * 0.5
        return [goal_distance, heading, proximity, ahead]

    def evaluate(self, states, actions, times, task: Task, *, order: int = 2) -> FeatureValues:
        """Features of states (T, 5) and actions (T, 2) at episode times (T,)."""
        states = np.atleast_2d(np.asarray(states, float))
        actions = np.atleast_2d(np.asarray(actions, float))
        times = np.atleast_1d(np.asarray(times, float))
        if not (len(states) == len(actions) == len(times)):
            raise LfdError(f"states, actions and times differ in length: {len(states)}, "
                           f"{len(actions)}, {len(times)}")
        count = len(states)
        jets = self._state_jets(states, np.asarray(task.goal, float),
                                np.asarray(task.obstacle_position(times), float).reshape(count, 2))
        ks = len(jets)
        state_jac = np.zeros((count, ks, 5))
        state_jac[:, :, :3] = np.stack([jet.grad for jet in jets], axis=1)
        state_hess = None
        if order >= 2:
            state_hess = np.zeros((count, ks, 5, 5))
            state_hess[:, :, :3, :3] = np.stack([jet.hess for jet in jets], axis=1)
        control_jac = np.zeros((count, 2, 2))
        control_jac[:, 0, 0], control_jac[:, 1, 1] = 2.0 * actions[:, 0], 2.0 * actions[:, 1]
        control_hess = np.zeros((count, 2, 2, 2))
        control_hess[:, 0, 0, 0] = control_hess[:, 1, 1, 1] = 2.0
        return FeatureValues(np.stack([jet.val for jet in jets], axis=1), state_jac, state_hess,
                             actions ** 2, control_jac, control_hess)
