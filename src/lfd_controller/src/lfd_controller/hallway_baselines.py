"""Controllers that learn nothing, for the hallway benchmark: a social-force controller and a
sampling (DWA-style) controller, both over the same HallwayTask the learned controller plans
with (no ROS). Each has a few settings that `tune` chooses on validation drives.

  * `SocialForceController` (Helbing and Molnar 1995, for a robot): a desired velocity toward
    the waypoint at `speed`, relaxed over `tau`, plus exponential pushes away from scan points
    and people (strength `push`, range `reach`); the unicycle turns toward the resulting
    velocity and drives its length.
  * `SamplingController` (Fox, Burgard and Thrun 1997, the dynamic window): constant (v, w)
    arcs within one step's acceleration, rolled out `lookahead` s with the people moving at
    their velocities; arcs that come within the robot's radius + `margin` of anything are out;
    the score is `progress` x distance made toward the waypoint + `clearance_weight` x the arc's
    smallest clearance (capped at 1 m) + the speed.
"""
import itertools
import math
from typing import Callable, Dict, Sequence

import numpy as np

from lfd_controller.hallway_features import HallwayTask

__all__ = ["SocialForceController", "SamplingController", "tune"]


class SocialForceController:
    def __init__(self, *, speed: float = 0.5, tau: float = 0.5, push: float = 1.0,
                 reach: float = 0.4, robot_radius: float = 0.18, person_radius: float = 0.25,
                 w_max: float = 2.0):
        self.speed, self.tau, self.push, self.reach = speed, tau, push, reach
        self.robot_radius, self.person_radius, self.w_max = robot_radius, person_radius, w_max

    def get_params(self) -> Dict:
        return {"speed": self.speed, "tau": self.tau, "push": self.push, "reach": self.reach}

    def act(self, state, t: float, task: HallwayTask) -> np.ndarray:
        position = np.asarray(state[:2], float)
        heading = np.array([math.cos(state[2]), math.sin(state[2])])
        velocity = state[3] * heading
        to_goal = task.waypoint - position
        desired = self.speed * to_goal / max(float(np.hypot(*to_goal)), 1e-9)
        force = (desired - velocity) / self.tau
        for centres, radius in ((task.points, self.robot_radius),
                                (task.people, self.robot_radius + self.person_radius)):
            if not len(centres):
                continue
            away = position - centres
            distance = np.maximum(np.hypot(*away.T), 1e-9)
            size = self.push * np.exp((radius - distance) / self.reach)
            force = force + (size / distance) @ away
        wanted = velocity + force * self.tau
        error = math.atan2(wanted[1], wanted[0]) - state[2]
        error = math.atan2(math.sin(error), math.cos(error))
        speed = float(np.clip(np.hypot(*wanted), 0.0, self.speed)) * max(0.0, math.cos(error))
        return np.array([speed, float(np.clip(2.0 * error, -self.w_max, self.w_max))])


class SamplingController:
    def __init__(self, *, v_max: float = 0.5, lookahead: float = 2.0, margin: float = 0.1,
                 progress: float = 2.0, clearance_weight: float = 0.5, robot_radius: float = 0.18,
                 person_radius: float = 0.25, w_max: float = 2.0, a_max: float = 1.0,
                 samples: int = 7):
        self.v_max, self.lookahead, self.margin = v_max, lookahead, margin
        self.progress, self.clearance_weight = progress, clearance_weight
        self.robot_radius, self.person_radius = robot_radius, person_radius
        self.w_max, self.a_max, self.samples = w_max, a_max, samples

    def get_params(self) -> Dict:
        return {"v_max": self.v_max, "lookahead": self.lookahead, "margin": self.margin,
                "progress": self.progress, "clearance_weight": self.clearance_weight}

    def act(self, state, t: float, task: HallwayTask) -> np.ndarray:
        v0 = float(state[3])
        speeds = np.clip(np.linspace(v0 - 0.5 * self.a_max, v0 + 0.5 * self.a_max, self.samples),
                         0.0, self.v_max)
        turns = np.linspace(-self.w_max, self.w_max, 2 * self.samples + 1)
        arcs = np.array(list(itertools.product(np.unique(speeds), turns)))
        steps = np.arange(1, int(self.lookahead / 0.2) + 1) * 0.2
        yaw = state[2] + arcs[:, 1:2] * steps
        xs = state[0] + np.cumsum(arcs[:, :1] * np.cos(yaw) * 0.2, axis=1)
        ys = state[1] + np.cumsum(arcs[:, :1] * np.sin(yaw) * 0.2, axis=1)
        clearance = np.full(len(arcs), 1.0)
        if len(task.points):
            gap = np.hypot(xs[..., None] - task.points[:, 0], ys[..., None] - task.points[:, 1])
            clearance = np.minimum(clearance, gap.min(axis=(1, 2)) - self.robot_radius)
        if len(task.people):
            people = task.people_at(t + steps)                       # (S, P, 2)
            gap = np.hypot(xs[..., None] - people[None, :, :, 0], ys[..., None] - people[None, :, :, 1])
            clearance = np.minimum(clearance, gap.min(axis=(1, 2)) - self.robot_radius
                                   - self.person_radius)
        made = (np.hypot(*(task.waypoint - state[:2]))
                - np.hypot(task.waypoint[0] - xs[:, -1], task.waypoint[1] - ys[:, -1]))
        score = self.progress * made + self.clearance_weight * clearance + arcs[:, 0]
        score[clearance < self.margin] = -np.inf
        if not np.isfinite(score).any():
            return np.zeros(2)
        return arcs[int(np.argmax(score))].astype(float)


def tune(make: Callable[..., object], grid: Dict[str, Sequence], score: Callable[[object], float]):
    """The controller make(**settings) with the best score(controller) (higher is better) over
    the grid; returns (controller, table of {settings, score})."""
    best, table = None, []
    for values in itertools.product(*grid.values()):
        settings = dict(zip(grid.keys(), values))
        controller = make(**settings)
        value = float(score(controller))
        table.append(dict(settings, score=value))
        if best is None or value > best[0]:
            best = (value, controller)
    return best[1], table
