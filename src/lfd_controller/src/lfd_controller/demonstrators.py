"""Person-like joystick drivers: a benchmark set of demonstrators that do NOT optimise our reward
(no ROS; imports nothing from the learner's features, rewards or planner, nor from robot_sim).

A driver steers the unicycle reactively toward the goal and swerves around the obstacle the way a
person with a joystick does:
  * it pushes the stick to a few positions only (`levels` per axis, e.g. 3-5), with hand noise;
  * it reacts late: what it decides now reaches the stick `delay` control steps later (1-2);
  * it avoids in its own way: how far ahead it looks at a moving obstacle, how early it starts to
    swerve and with how wide a margin, how much it slows near the obstacle;
  * it brakes late near the goal (overshoots a little), and once inside the goal it lets go of the
    stick and sits still for a while before the recording stops (an idle tail).
Every demonstration draws a new temperament (speed, margin, delay, noise, side preference) around
its style. The commands go through the same joystick mapping as joy_teleop (teleop.JoyMapping),
so the same driver can publish sensor_msgs/Joy in ROS (see `axes`) or drive the model directly.

Contract: `PersonLikeDriver(style, rng).reset(scenario)` then `axes(state, t)` -> stick axes and
`command(state, t)` -> (v_cmd, w_cmd) once per control step; `demonstrate(scenario, start)` ->
Demonstration with source "person:<style>" and meta {style, delay, reached, collided, idle_steps}.
"""
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Dict, List, Optional, Sequence

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.errors import LfdError
from lfd_controller.teleop import JoyMapping, JoyTeleop
from robot_common.tasks import Scenario, scenario_from_dict


@dataclass(frozen=True)
class DrivingStyle:
    """How one kind of person drives (the means; each demonstration draws around them).

    cruise: stick fraction pushed forward on a free road; levels: stick positions per axis
    (including 0); lookahead: seconds ahead a moving obstacle is extrapolated; trigger: distance
    (m) at which swerving starts; margin: extra clearance (m) kept beyond touching; slow_near:
    speed factor right next to the obstacle (1 = no slowing); turn_gain: stick per rad of heading
    error; brake: goal distance (m) below which the stick is pulled back; noise: hand noise (stick
    fraction, std); delay: (min, max) control steps of reaction delay."""

    name: str
    cruise: float
    levels: int
    lookahead: float
    trigger: float
    margin: float
    slow_near: float
    turn_gain: float
    brake: float
    noise: float
    delay: Sequence[int] = (1, 2)


STYLES: Dict[str, DrivingStyle] = {
    # early wide swerve, slow, three stick positions, slows down a lot next to the obstacle
    "cautious": DrivingStyle("cautious", cruise=0.7, levels=3, lookahead=1.5, trigger=1.6,
                             margin=0.35, slow_near=0.5, turn_gain=1.2, brake=0.6, noise=0.04),
    # late tight swerve, fast, five stick positions, hardly slows, brakes late (overshoots)
    "sporty": DrivingStyle("sporty", cruise=1.0, levels=5, lookahead=0.8, trigger=0.9,
                           margin=0.15, slow_near=0.9, turn_gain=2.0, brake=0.3, noise=0.06),
    # in between, four positions, slows moderately, the longest reaction delay
    "steady": DrivingStyle("steady", cruise=0.85, levels=4, lookahead=1.1, trigger=1.2,
                           margin=0.25, slow_near=0.7, turn_gain=1.5, brake=0.45, noise=0.05,
                           delay=(2, 2)),
}


def quantise(value: float, levels: int) -> float:
    """The nearest of `levels` stick positions in [-1, 1] per side (levels includes 0 and full)."""
    steps = max(1, levels - 1)
    value = max(-1.0, min(1.0, value))
    return round(value * steps) / steps


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


class PersonLikeDriver:
    """A reactive joystick driver of one style; a new temperament per `reset` (see module doc)."""

    def __init__(self, style, random_state=None, mapping: Optional[JoyMapping] = None):
        if isinstance(style, str):
            if style not in STYLES:
                raise LfdError(f"unknown driving style {style!r}; known: {sorted(STYLES)}")
            style = STYLES[style]
        self.style = style
        self.rng = np.random.default_rng(random_state)
        self.mapping = mapping or JoyMapping()
        self.teleop = JoyTeleop(self.mapping)
        self.scenario: Optional[Scenario] = None

    def reset(self, scenario: Scenario) -> "PersonLikeDriver":
        """A new drive with a new temperament."""
        s, rng = self.style, self.rng
        self.scenario = scenario
        self.cruise = float(np.clip(s.cruise * rng.uniform(0.85, 1.1), 0.3, 1.0))
        self.margin = s.margin * rng.uniform(0.8, 1.3)
        self.trigger = s.trigger * rng.uniform(0.85, 1.2)
        self.lookahead = s.lookahead * rng.uniform(0.8, 1.2)
        self.turn_gain = s.turn_gain * rng.uniform(0.85, 1.2)
        self.brake = s.brake * rng.uniform(0.8, 1.2)
        self.noise = s.noise * rng.uniform(0.5, 1.5)
        self.delay = int(rng.integers(s.delay[0], s.delay[1] + 1))
        self.side_bias = rng.uniform(-0.15, 0.15)     # which side this person prefers when unsure
        self.idle_steps = int(rng.integers(5, 16))    # sitting still at the goal before stopping
        self.side: Optional[float] = None
        self.pending = deque([(0.0, 0.0)] * self.delay)
        return self

    # --- deciding -------------------------------------------------------------------------
    def _intent(self, state, t: float):
        """(linear, angular) stick fractions this person wants now."""
        scenario = self.scenario
        px, py, yaw, v = state[0], state[1], state[2], state[3]
        goal = np.asarray(scenario.goal, float)
        to_goal = goal - (px, py)
        goal_dist = float(np.hypot(*to_goal))
        if goal_dist < 0.85 * scenario.goal_tolerance:
            return 0.0, 0.0                            # there: let go of the stick
        goal_bearing = math.atan2(to_goal[1], to_goal[0])
        obstacle = np.asarray(scenario.obstacle.position(t), float)
        seen_ahead = np.asarray(scenario.obstacle.position(t + self.lookahead), float)
        # where this person thinks the obstacle will be when passing it
        distance_now = float(np.hypot(*(obstacle - (px, py))))
        # extrapolated for about the time it takes to get there (at most the lookahead)
        reach = min(1.0, distance_now / max(abs(v), 0.25) / max(self.lookahead, 1e-6))
        predicted = obstacle + reach * (seen_ahead - obstacle)
        velocity = (seen_ahead - obstacle) / max(self.lookahead, 1e-6)
        to_obst = predicted - (px, py)
        obst_dist = float(np.hypot(*to_obst))
        obst_bearing = math.atan2(to_obst[1], to_obst[0])
        keep = scenario.clearance + self.margin
        heading = goal_bearing
        relative = _wrap(obst_bearing - goal_bearing)
        in_way = (obst_dist < goal_dist + keep and abs(relative) < math.pi / 2
                  and abs(obst_dist * math.sin(relative)) < keep)
        if obst_dist < self.trigger and (in_way or self.side is not None) and obst_dist > 1e-6:
            if self.side is None:
                # pass behind a moving obstacle; else on the side away from its offset (or the
                # side this person prefers when it is straight ahead)
                lateral = -math.sin(goal_bearing) * velocity[0] + math.cos(goal_bearing) * velocity[1]
                if abs(lateral) > 0.05:
                    self.side = -1.0 if lateral > 0 else 1.0
                else:
                    self.side = -1.0 if relative + self.side_bias > 0 else 1.0
            half = math.asin(min(1.0, keep / obst_dist))
            tangent = obst_bearing + self.side * half
            # head for the tangent unless the goal bearing already clears it
            if self.side * _wrap(goal_bearing - tangent) < 0:
                heading = tangent
            if not in_way and abs(relative) > half + 0.3:
                self.side = None                        # passed: back to the goal
        elif self.side is not None and obst_dist >= self.trigger:
            self.side = None
        error = _wrap(heading - yaw)
        speed = self.cruise * max(0.0, math.cos(error)) ** 2
        if obst_dist < self.trigger:
            closeness = 1.0 - max(0.0, obst_dist - keep) / max(self.trigger - keep, 1e-6)
            speed *= 1.0 - (1.0 - self.style.slow_near) * min(1.0, max(0.0, closeness))
        if goal_dist < self.brake:
            speed *= max(0.3, goal_dist / self.brake)
        bearing_now = _wrap(math.atan2(obstacle[1] - py, obstacle[0] - px) - yaw)
        if distance_now < scenario.clearance + 0.12 and abs(bearing_now) < math.pi / 2:
            speed = 0.0                                 # about to touch it: stop and turn away
        speed = max(speed, 0.0)
        angular = self.turn_gain * error * self.mapping.scale_angular ** -1 * 1.0
        return speed, angular

    def axes(self, state, t: float) -> List[float]:
        """The stick this person holds now (sensor_msgs/Joy axes): today's intent reaches the
        stick `delay` steps later, at one of `levels` positions, with hand noise."""
        if self.scenario is None:
            raise LfdError("PersonLikeDriver: reset(scenario) before driving")
        linear, angular = self._intent(np.asarray(state, float), float(t))
        lin_q = quantise(linear, self.style.levels)
        if linear > 0.1 and lin_q == 0.0:
            lin_q = quantise(1.0 / max(1, self.style.levels - 1), self.style.levels)   # a nudge
        ang_q = quantise(angular, self.style.levels)
        if lin_q or ang_q:
            lin_q += self.noise * self.rng.standard_normal()
            ang_q += self.noise * self.rng.standard_normal()
        self.pending.append((max(-1.0, min(1.0, lin_q)), max(-1.0, min(1.0, ang_q))))
        lin_now, ang_now = self.pending.popleft()
        axes = [0.0] * 8
        mapping = self.mapping
        for index, fraction in ((mapping.axis_linear, lin_now), (mapping.axis_angular, ang_now)):
            if fraction:
                magnitude = mapping.deadzone + abs(fraction) * (1.0 - mapping.deadzone)
                axes[index] = math.copysign(min(1.0, magnitude), fraction)
        return axes

    def buttons(self) -> List[int]:
        """The dead-man button held (sensor_msgs/Joy buttons)."""
        buttons = [0] * 11
        buttons[self.mapping.enable_button] = 1
        return buttons

    def command(self, state, t: float) -> np.ndarray:
        """(v_cmd, w_cmd) as joy_teleop turns this person's stick into cmd_vel."""
        cmd, _ = self.teleop.update(self.axes(state, t), self.buttons())
        return np.array(cmd, float)

    # --- whole drives -------------------------------------------------------------------------
    def drive(self, scenario: Scenario, start, *, max_time: Optional[float] = None,
              execution_noise: Sequence[float] = (0.0, 0.0)):
        """One drive: (actions (T, 2), states x_1..x_T, reached, collided, idle steps).
        execution_noise (std of v_cmd, w_cmd): noise added to the command the robot executes,
        while `actions` keep the person's own commands (DART data)."""
        self.reset(scenario)
        model = scenario.model()
        steps = int(round((max_time or scenario.max_time) / scenario.dt))
        state = np.asarray(start, float)
        actions, states = [], []
        reached = collided = False
        idle = 0
        for k in range(steps):
            t = k * scenario.dt
            action = self.command(state, t)
            executed = action + np.asarray(execution_noise, float) * self.rng.standard_normal(2)
            state = model.step(state, executed)
            actions.append(action)
            states.append(state)
            if scenario.collides(state, t + scenario.dt):
                collided = True
                break
            inside = bool(scenario.reached(state))
            reached = reached or inside
            idle = idle + 1 if inside and not np.any(action) else 0    # sitting still there
            if idle >= self.idle_steps:
                break
        return np.array(actions), np.array(states), reached and not collided, collided, idle

    def demonstrate(self, scenario: Scenario, start, t0: float = 0.0) -> Demonstration:
        if t0:
            raise LfdError("person-like drives start at episode time 0")
        actions, states, reached, collided, idle = self.drive(scenario, start)
        return Demonstration(scenario, start, actions, 0.0, states, source=f"person:{self.style.name}",
                             meta={"style": self.style.name, "delay": self.delay, "reached": bool(reached),
                                   "collided": bool(collided), "idle_steps": int(idle)})

    def success(self, scenario: Scenario, start) -> Dict:
        """{reached, collided, success, time} of one drive (the driver's own reference figure)."""
        actions, states, reached, collided, _ = self.drive(scenario, start)
        inside = np.flatnonzero(scenario.reached(states)) if len(states) else []
        arrival = (inside[0] + 1) * scenario.dt if len(inside) else float("nan")
        return {"reached": bool(reached), "collided": bool(collided),
                "success": bool(reached and not collided), "time": float(arrival)}


def person_demos(scenario: Scenario, style: str, starts: Sequence[np.ndarray], seed: int = 0,
                 only_successful: bool = True, max_tries: int = 3) -> List[Demonstration]:
    """Demonstrations of one style (or "mixed": the styles in turn) from `starts`. A person
    re-does a failed drive (new temperament) up to max_tries times, as people keep good takes."""
    names = sorted(STYLES) if style == "mixed" else [style]
    drivers = [PersonLikeDriver(name, seed * 1000 + i) for i, name in enumerate(names)]
    demos = []
    for k, start in enumerate(starts):
        driver = drivers[k % len(drivers)]
        for _ in range(max_tries):
            demo = driver.demonstrate(scenario, start)
            if demo.meta["reached"] or not only_successful:
                break
        if demo.meta["reached"] or not only_successful:
            demos.append(demo)
    return demos


def dart_demos(scenario: Scenario, style: str, starts: Sequence[np.ndarray], seed: int = 0,
               noise: Sequence[float] = (0.1, 0.4)) -> List[Demonstration]:
    """DART data for behaviour cloning: the same drives with noise injected into the executed
    commands; states are the ones reached, actions the person's own (noise-free) commands."""
    names = sorted(STYLES) if style == "mixed" else [style]
    drivers = [PersonLikeDriver(name, seed * 1000 + i) for i, name in enumerate(names)]
    demos = []
    for k, start in enumerate(starts):
        driver = drivers[k % len(drivers)]
        actions, states, reached, collided, idle = driver.drive(scenario, start, execution_noise=noise)
        if len(actions) >= 2:
            demos.append(Demonstration(scenario, start, actions, 0.0, states,
                                       source=f"person:{driver.style.name}:dart",
                                       meta={"style": driver.style.name, "reached": bool(reached)}))
    return demos


def unseen_layouts() -> List[Scenario]:
    """Two obstacle/goal layouts no standard scenario shows (for generalisation figures)."""
    base = {"dt": 0.1, "max_time": 15.0, "bounds": [-3.5, -2.0, 1.0, 2.0],
            "robot": {"radius": 0.18, "v_max": 0.6, "w_max": 2.0, "a_max": 1.0, "alpha_max": 4.0},
            "start": {"x": [-2.7, -2.2], "y": [-0.9, 0.9], "yaw": [-0.6, 0.6]}}
    offset = dict(base, name="layout_offset_goal", goal={"x": 0.2, "y": 0.9, "tolerance": 0.25},
                  obstacle={"x": -1.0, "y": 0.4, "radius": 0.3, "motion": {"kind": "static"}})
    crossing = dict(base, name="layout_crossing", goal={"x": 0.0, "y": -0.8, "tolerance": 0.25},
                    obstacle={"x": -1.5, "y": 1.0, "radius": 0.22,
                              "motion": {"kind": "linear", "velocity": [0.0, -0.2]}})
    return [scenario_from_dict(offset), scenario_from_dict(crossing)]


def with_max_time(scenario: Scenario, max_time: float) -> Scenario:
    return replace(scenario, max_time=max_time)
