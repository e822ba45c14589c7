"""Navigation tasks for the unicycle: a goal, one static or moving obstacle, random starts (no ROS).

The task geometry shared by the learners (lfd_controller) and the simulators (robot_sim). A task is
written as YAML (robot_sim keeps the standard ones in config/scenarios/*.yaml):

    name: static_obstacle
    dt: 0.1                     # simulation step (s)
    max_time: 15.0              # episode time limit (s)
    bounds: [-3.5, -2.0, 1.0, 2.0]            # arena [xmin, ymin, xmax, ymax]; leaving it = collision
    goal: {x: 0.0, y: 0.0, tolerance: 0.25}
    robot: {radius: 0.18, v_max: 0.6, w_max: 2.0, a_max: 1.0, alpha_max: 4.0}
    obstacle: {x: -1.2, y: 0.0, radius: 0.25,
               motion: {kind: linear, velocity: [0.0, 0.3]}}     # or kind: static / oscillate
    start: {x: [-2.7, -2.2], y: [-0.9, 0.9], yaw: [-0.6, 0.6]}  # uniform ranges; yaw relative to the
                                                                # bearing to the goal
Obstacle positions are indexed by episode time t (seconds since the episode started).
"""
import math
from dataclasses import dataclass, field
from typing import Dict, List, Sequence, Union

import numpy as np
import yaml

from robot_common.errors import TaskError
from robot_common.unicycle import Unicycle, UnicycleLimits

__all__ = ["MOTION_KINDS", "ObstacleMotion", "Scenario", "scenario_from_dict", "scenario_from_yaml"]

MOTION_KINDS = ("static", "linear", "oscillate")


@dataclass(frozen=True)
class ObstacleMotion:
    """A disc obstacle whose centre is a smooth function of episode time."""

    x: float
    y: float
    radius: float
    kind: str = "static"
    velocity: Sequence[float] = (0.0, 0.0)
    amplitude: Sequence[float] = (0.0, 0.0)
    period: float = 1.0

    def __post_init__(self):
        if self.kind not in MOTION_KINDS:
            raise TaskError(f"obstacle motion kind must be one of {MOTION_KINDS}, got {self.kind!r}")
        if not self.radius > 0:
            raise TaskError(f"obstacle radius must be positive, got {self.radius!r}")
        if self.kind == "oscillate" and not self.period > 0:
            raise TaskError(f"an oscillating obstacle needs a positive period, got {self.period!r}")

    @property
    def moving(self) -> bool:
        return self.kind != "static"

    def position(self, t) -> np.ndarray:
        """Centre(s) at episode time(s) t: shape (..., 2)."""
        t = np.asarray(t, dtype=float)[..., None]
        centre = np.array([self.x, self.y])
        if self.kind == "linear":
            return centre + t * np.asarray(self.velocity, dtype=float)
        if self.kind == "oscillate":
            return centre + np.sin(2.0 * math.pi * t / self.period) * np.asarray(self.amplitude, float)
        return np.broadcast_to(centre, t.shape[:-1] + (2,)).copy()

    def velocity_at(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        if self.kind == "linear":
            return np.broadcast_to(np.asarray(self.velocity, float), t.shape[:-1] + (2,)).copy()
        if self.kind == "oscillate":
            omega = 2.0 * math.pi / self.period
            return omega * np.cos(omega * t) * np.asarray(self.amplitude, float)
        return np.zeros(t.shape[:-1] + (2,))


@dataclass
class Scenario:
    """Goal, obstacle, robot limits, arena and start distribution of one navigation task."""

    name: str
    goal: np.ndarray
    obstacle: ObstacleMotion
    goal_tolerance: float = 0.25
    robot_radius: float = 0.18
    limits: UnicycleLimits = field(default_factory=UnicycleLimits)
    dt: float = 0.1
    max_time: float = 15.0
    bounds: Sequence[float] = (-3.5, -2.0, 1.0, 2.0)
    start_ranges: Dict[str, Sequence[float]] = field(default_factory=lambda: {
        "x": (-2.7, -2.2), "y": (-0.9, 0.9), "yaw": (-0.6, 0.6)})
    source: Dict = field(default_factory=dict)

    def model(self) -> Unicycle:
        return Unicycle(self.dt, self.limits)

    @property
    def clearance(self) -> float:
        """Centre distance below which robot and obstacle touch."""
        return self.robot_radius + self.obstacle.radius

    def obstacle_distance(self, positions, t) -> np.ndarray:
        positions = np.asarray(positions, dtype=float)
        return np.linalg.norm(positions[..., :2] - self.obstacle.position(t), axis=-1)

    def collides(self, positions, t) -> np.ndarray:
        """True where the robot at positions (..., >=2) and time(s) t hits the obstacle or leaves
        the arena."""
        positions = np.asarray(positions, dtype=float)
        xmin, ymin, xmax, ymax = self.bounds
        r = self.robot_radius
        outside = ((positions[..., 0] - r < xmin) | (positions[..., 0] + r > xmax)
                   | (positions[..., 1] - r < ymin) | (positions[..., 1] + r > ymax))
        return outside | (self.obstacle_distance(positions, t) < self.clearance)

    def reached(self, positions) -> np.ndarray:
        positions = np.asarray(positions, dtype=float)
        return np.linalg.norm(positions[..., :2] - self.goal, axis=-1) < self.goal_tolerance

    def sample_start(self, rng: Union[np.random.Generator, int, None] = None,
                     margin: float = 0.3) -> np.ndarray:
        """A random start state (zero speeds) clear of the obstacle at t = 0 by `margin`."""
        rng = np.random.default_rng(rng)
        for _ in range(1000):
            x, y = (rng.uniform(*self.start_ranges[key]) for key in ("x", "y"))
            bearing = math.atan2(self.goal[1] - y, self.goal[0] - x)
            yaw = bearing + rng.uniform(*self.start_ranges["yaw"])
            state = np.array([x, y, math.atan2(math.sin(yaw), math.cos(yaw)), 0.0, 0.0])
            if (self.obstacle_distance(state, 0.0) > self.clearance + margin
                    and not self.collides(state, 0.0)):
                return state
        raise TaskError(f"scenario {self.name}: no start clear of the obstacle in the start ranges")

    def sample_starts(self, count: int, seed: int) -> List[np.ndarray]:
        rng = np.random.default_rng(seed)
        return [self.sample_start(rng) for _ in range(count)]

    def to_dict(self) -> Dict:
        """The scenario as plain data (the same layout as its YAML file)."""
        obstacle = self.obstacle
        motion = {"kind": obstacle.kind}
        if obstacle.kind == "linear":
            motion["velocity"] = [float(v) for v in obstacle.velocity]
        elif obstacle.kind == "oscillate":
            motion.update(amplitude=[float(a) for a in obstacle.amplitude], period=obstacle.period)
        lim = self.limits
        return {"name": self.name, "dt": self.dt, "max_time": self.max_time,
                "bounds": [float(b) for b in self.bounds],
                "goal": {"x": float(self.goal[0]), "y": float(self.goal[1]),
                         "tolerance": self.goal_tolerance},
                "robot": {"radius": self.robot_radius, "v_max": lim.v_max, "w_max": lim.w_max,
                          "a_max": lim.a_max, "alpha_max": lim.alpha_max},
                "obstacle": {"x": obstacle.x, "y": obstacle.y, "radius": obstacle.radius,
                             "motion": motion},
                "start": {key: [float(v) for v in value] for key, value in self.start_ranges.items()}}

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


def _number(data: Dict, key: str, default=None, where: str = "") -> float:
    value = data.get(key, default)
    if value is None:
        raise TaskError(f"scenario{where}: missing '{key}'")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise TaskError(f"scenario{where}: '{key}' must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise TaskError(f"scenario{where}: '{key}' must be finite, got {value!r}")
    return value


def _pair(value, what: str) -> List[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise TaskError(f"scenario: {what} must be a list of two numbers, got {value!r}")
    try:
        return [float(v) for v in value]
    except (TypeError, ValueError):
        raise TaskError(f"scenario: {what} must be a list of two numbers, got {value!r}") from None


def scenario_from_dict(data: Dict) -> Scenario:
    """A Scenario from parsed YAML; TaskError names what is missing or malformed."""
    if not isinstance(data, dict):
        raise TaskError(f"a scenario must be a mapping, got {type(data).__name__}")
    for key in ("goal", "obstacle"):
        if not isinstance(data.get(key), dict):
            raise TaskError(f"scenario: missing or malformed '{key}' section")
    goal, obstacle_data = data["goal"], data["obstacle"]
    robot = data.get("robot") or {}
    motion = obstacle_data.get("motion") or {"kind": "static"}
    kind = str(motion.get("kind", "static"))
    obstacle = ObstacleMotion(
        x=_number(obstacle_data, "x", where=" obstacle"), y=_number(obstacle_data, "y", where=" obstacle"),
        radius=_number(obstacle_data, "radius", 0.25, " obstacle"), kind=kind,
        velocity=tuple(_pair(motion.get("velocity", [0.0, 0.0]), "obstacle velocity")),
        amplitude=tuple(_pair(motion.get("amplitude", [0.0, 0.0]), "obstacle amplitude")),
        period=_number(motion, "period", 1.0, " obstacle motion"))
    limits = UnicycleLimits(**{key: _number(robot, key, getattr(UnicycleLimits, key), " robot")
                               for key in ("v_max", "w_max", "a_max", "alpha_max")})
    start = data.get("start") or {}
    ranges = {key: tuple(_pair(start.get(key, default), f"start {key}"))
              for key, default in (("x", (-2.7, -2.2)), ("y", (-0.9, 0.9)), ("yaw", (-0.6, 0.6)))}
    bounds = data.get("bounds", [-3.5, -2.0, 1.0, 2.0])
    if not isinstance(bounds, (list, tuple)) or len(bounds) != 4 or not (
            bounds[0] < bounds[2] and bounds[1] < bounds[3]):
        raise TaskError(f"scenario: bounds must be [xmin, ymin, xmax, ymax], got {bounds!r}")
    scenario = Scenario(
        name=str(data.get("name", "unnamed")),
        goal=np.array([_number(goal, "x", where=" goal"), _number(goal, "y", where=" goal")]),
        obstacle=obstacle, goal_tolerance=_number(goal, "tolerance", 0.25, " goal"),
        robot_radius=_number(robot, "radius", 0.18, " robot"), limits=limits,
        dt=_number(data, "dt", 0.1), max_time=_number(data, "max_time", 15.0),
        bounds=[float(b) for b in bounds], start_ranges=ranges, source=dict(data))
    if scenario.dt <= 0 or scenario.max_time <= 0:
        raise TaskError(f"scenario: dt and max_time must be positive, got {scenario.dt}, "
                       f"{scenario.max_time}")
    return scenario


def scenario_from_yaml(text: str) -> Scenario:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise TaskError(f"scenario is not valid YAML: {err}") from err
    return scenario_from_dict(data)
