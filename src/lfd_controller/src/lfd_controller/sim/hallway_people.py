"""Simulated people driving through a building (robot_sim.hallway scenes) with the joystick
(no ROS; benchmarks, tests and the demo only).

A family driver (sim.families) sees one goal and one obstacle; in a hall a person looks at a
point a little ahead on the path (the carrot, 1.5 m) and at whatever threatens most: of the
tracked people and the nearest scan points ahead, the one that comes closest within the next
2 s. `HallwayDriver` gives the family that view at every step (a Scenario with the carrot as
goal and the threat as a constant-velocity obstacle), so the six families keep their own ways
of avoiding (swerving, fields, velocity obstacles, social forces, sampling, yielding) and their
hands (delay, stick, noise). `hallway_demonstration` records a drive with the HallwayTask the
robot saw at each step (its waypoint chosen as HallwayController chooses it: what learning uses).
"""
import math
from dataclasses import replace
from typing import Dict, List, Optional, Tuple

import numpy as np

from lfd_controller.hallway import HALLWAY_SAFETY, TaskBuilder, hallway_scenario
from lfd_controller.hallway_features import PathFollower
from lfd_controller.sim.families import make_person
from robot_common.tasks import ObstacleMotion
from robot_sim.hallway import PERSON_RADIUS, DriveResult, HallwayScene, drive

__all__ = ["HallwayDriver", "hallway_demonstration", "drive_figures"]

CARROT = 1.5


class HallwayDriver:
    """A person of `family` driving a hallway scene (module docstring); a policy for
    robot_sim.hallway.drive, recording the robot's HallwayTask at each step in `tasks`."""

    def __init__(self, family: str, seed: int = 0, person=None):
        self.person = make_person(family, seed, person)
        self.family = family

    def reset(self, scene: HallwayScene) -> "HallwayDriver":
        self.scene = scene
        self.view = replace(hallway_scenario(scene.dt), goal=np.asarray(scene.goal, float),
                            goal_tolerance=scene.goal_tolerance, robot_radius=scene.robot_radius)
        self.person.reset(self.view)
        self.follower = PathFollower(scene.path, lookahead=CARROT)
        self.seen = TaskBuilder(scene.path, lookahead=HALLWAY_SAFETY["lookahead"])
        self.tasks: List = []
        return self

    def __call__(self, state, t: float, observation) -> np.ndarray:
        self.look(state, t, observation)
        return self.person.command(state, t)

    def axes(self, state, t: float, observation) -> List[float]:
        """The stick this person holds now (sensor_msgs/Joy axes, with `person.buttons()` the
        dead-man button): for driving through a joystick topic and joy_teleop, which turns it
        into the command `__call__` gives."""
        self.look(state, t, observation)
        return self.person.axes(state, t)

    def look(self, state, t: float, observation) -> None:
        """What the person sees at this step: the carrot as goal, the threat as obstacle."""
        carrot = self.follower.update(state[:2])
        self.tasks.append(self.seen(state, t, observation.angles, observation.ranges,
                                    observation.people, observation.velocities))
        threat, velocity, radius = self._threat(state, self.tasks[-1], carrot)
        self.person.scenario = replace(
            self.view, goal=carrot,
            obstacle=ObstacleMotion(float(threat[0] - t * velocity[0]),
                                    float(threat[1] - t * velocity[1]), radius, "linear",
                                    tuple(float(v) for v in velocity)))

    def _threat(self, state, task, carrot) -> Tuple[np.ndarray, np.ndarray, float]:
        """(position, velocity, radius) of what comes closest within 2 s (far away: nothing)."""
        position = np.asarray(state[:2], float)
        heading = math.atan2(carrot[1] - position[1], carrot[0] - position[0])
        robot_velocity = state[3] * np.array([math.cos(state[2]), math.sin(state[2])])
        candidates = [(p, v, PERSON_RADIUS) for p, v in zip(task.people, task.velocities)]
        for point in task.points:
            offset = point - position
            ahead = math.cos(math.atan2(offset[1], offset[0]) - heading) > 0.5
            if ahead and np.hypot(*offset) < 1.2:
                candidates.append((point, np.zeros(2), 0.05))
        best, best_gap = None, math.inf
        for where, velocity, radius in candidates:
            relative, motion = where - position, velocity - robot_velocity
            lead = np.clip(-np.dot(relative, motion) / max(np.dot(motion, motion), 1e-9), 0, 2.0)
            gap = float(np.hypot(*(relative + lead * motion))) - radius
            if gap < best_gap:
                best, best_gap = (where, velocity, radius), gap
        if best is None:
            return position + 1e3, np.zeros(2), 0.05
        return np.asarray(best[0], float), np.asarray(best[1], float), best[2]


def hallway_demonstration(driver: HallwayDriver, scene: HallwayScene,
                          max_time: Optional[float] = None) -> Tuple[DriveResult, List]:
    """One drive by `driver` through `scene`: (the drive, the HallwayTask at each step)."""
    result = drive(scene, driver.reset(scene), max_time=max_time)
    return result, driver.tasks[:len(result.actions)]


def drive_figures(result: DriveResult, dt: float = 0.1) -> Dict:
    """{success, collision, time, ended, closest}: time to the goal (NaN: not reached), when
    the drive ended (the goal, a collision or the time limit); closest is the smallest
    edge-to-edge distance to a person over the drive (inf: nobody near)."""
    return {"success": bool(result.success), "collision": result.collision,
            "time": len(result.actions) * dt if result.reached else float("nan"),
            "ended": len(result.actions) * dt,
            "closest": float(np.min(result.person_gaps)) if len(result.person_gaps) else math.inf}
