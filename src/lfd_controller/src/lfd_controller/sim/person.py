"""A simulated person at the joystick: what every demonstrator family shares (no ROS).

A family (sim.families) decides what the person wants - a speed (m/s) and a turn rate (rad/s) -
from what the person sees; this module turns that into a joystick the way a person's hand does:

  * per-person variation (`Person`, drawn by `draw_person`): preferred speed 0.2-0.6 m/s,
    reaction delay 0-300 ms (0-3 control steps), stick positions per axis (quantisation), hand
    noise, side preference, clearance (aggressive 0.05 m .. cautious 0.45 m beyond touching),
    overshoot at the goal (0: brakes in time; > 0: aims that far past the goal, then turns back);
  * a quantised stick held with error diffusion (a person holding 0.4 m/s on a stick with
    positions at 0.3 and 0.6 m/s alternates between them, so the average is what they want);
  * the reaction delay: what the person decides now reaches the stick `delay` steps later;
  * hand noise on a stick that is pushed; letting go at the goal and sitting still for a while
    before the recording stops (an idle tail);
  * a little variation from drive to drive (the same person is never exactly the same twice).

The stick goes through the same mapping as joy_teleop (teleop.JoyMapping); `axes` is what a
person publishes as sensor_msgs/Joy, `command` what joy_teleop then sends as cmd_vel.
Nothing here imports the learner's features, rewards or planner: no family optimises them.
"""
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Dict, List, Optional

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.errors import LfdError
from lfd_controller.teleop import JoyMapping, JoyTeleop
from robot_common.tasks import Scenario
from robot_common.unicycle import saturate_inverse

# The joystick scaling the simulated people drive with (joy_teleop's scale_linear and
# scale_angular must match when they drive through ROS): full stick commands 0.8 m/s, which the
# robot's smooth speed limit turns into about 0.56 m/s.
PERSON_MAPPING = JoyMapping(scale_linear=0.8, scale_angular=2.0)
STICK_LEVELS = (3, 4, 5, 7, 9)


@dataclass(frozen=True)
class Person:
    """One person's way of driving (see the module doc for the ranges `draw_person` uses).

    speed: preferred cruising speed (m/s); delay: reaction delay (control steps); levels: stick
    positions per axis (including 0 and full); noise: hand noise (stick fraction, std); side: +1
    passes obstacles on their left when unsure, -1 on their right; clearance: extra distance (m)
    kept beyond touching; overshoot: m past the goal this person aims before turning back (0:
    brakes in time); turn_gain: rad/s of turn per rad of heading error; idle_steps: steps sitting
    still at the goal before the recording stops."""

    speed: float
    delay: int
    levels: int
    noise: float
    side: float
    clearance: float
    overshoot: float
    turn_gain: float
    idle_steps: int = 10

    def __post_init__(self):
        if not 0.05 <= self.speed <= 1.0:
            raise LfdError(f"a person's preferred speed must be in [0.05, 1] m/s, got {self.speed!r}")
        if self.delay < 0 or self.levels < 2 or self.noise < 0 or self.clearance < 0:
            raise LfdError(f"bad person: delay {self.delay!r} (>= 0), levels {self.levels!r} (>= 2), "
                           f"noise {self.noise!r} and clearance {self.clearance!r} (>= 0)")


def draw_person(rng, *, speed=(0.2, 0.6), delay=(0, 3), clearance=(0.05, 0.45),
                noise=(0.01, 0.08), overshoot_chance: float = 0.4) -> Person:
    """A random person: uniform preferred speed (m/s), reaction delay (steps, inclusive), clearance
    (m), hand noise; stick positions from STICK_LEVELS; a side; an overshoot of 0.1-0.35 m with
    probability overshoot_chance."""
    rng = np.random.default_rng(rng)
    overshoot = float(rng.uniform(0.1, 0.35)) if rng.random() < overshoot_chance else 0.0
    return Person(speed=float(rng.uniform(*speed)), delay=int(rng.integers(delay[0], delay[1] + 1)),
                  levels=int(rng.choice(STICK_LEVELS)), noise=float(rng.uniform(*noise)),
                  side=float(rng.choice([-1.0, 1.0])), clearance=float(rng.uniform(*clearance)),
                  overshoot=overshoot, turn_gain=float(rng.uniform(1.5, 3.0)),
                  idle_steps=int(rng.integers(5, 16)))


def quantise(value: float, levels: int) -> float:
    """The nearest of `levels` stick positions in [-1, 1] per side (levels includes 0 and full)."""
    steps = max(1, levels - 1)
    value = max(-1.0, min(1.0, value))
    return round(value * steps) / steps


def wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


class SimulatedPerson:
    """A person of one family at the joystick. Subclasses implement `intent(state, t)` -> (speed
    m/s, turn rate rad/s) and may use `self.person`, `self.target` (the goal this person steers to,
    past it when overshooting), `self.obstacle_seen(t)` and `self.obstacle_velocity(t)`.

    Contract: `reset(scenario)` then `axes(state, t)` / `command(state, t)` once per control step;
    `demonstrate(scenario, start)` -> Demonstration (source "person:<family>", meta with the
    person); `success(scenario, start)` -> this person's own figures for one drive."""

    family = "person"

    def __init__(self, person: Optional[Person] = None, random_state=None,
                 mapping: Optional[JoyMapping] = None):
        self.rng = np.random.default_rng(random_state)
        self.person = person if person is not None else draw_person(self.rng)
        self.mapping = mapping or PERSON_MAPPING
        self.teleop = JoyTeleop(self.mapping)
        self.scenario: Optional[Scenario] = None

    # --- per drive -------------------------------------------------------------------------
    def reset(self, scenario: Scenario) -> "SimulatedPerson":
        """A new drive: the same person, a little different today (speed and gains +-8 %)."""
        self.scenario = scenario
        base, rng = self.person, self.rng
        self.today = replace(base, speed=float(np.clip(base.speed * rng.uniform(0.92, 1.08), 0.05, 1.0)),
                             turn_gain=base.turn_gain * rng.uniform(0.92, 1.08))
        self.pending = deque([(0.0, 0.0)] * base.delay)
        self.residual = np.zeros(2)
        self.passed_goal = False
        self.approach: Optional[np.ndarray] = None
        self.start_drive()
        return self

    def start_drive(self) -> None:
        """Family state reset at the start of each drive (override)."""

    def intent(self, state: np.ndarray, t: float):
        raise NotImplementedError

    # --- what the person sees ----------------------------------------------------------------
    def obstacle_seen(self, t: float) -> np.ndarray:
        return np.asarray(self.scenario.obstacle.position(t), float)

    def obstacle_velocity(self, t: float, span: float = 0.3) -> np.ndarray:
        """The obstacle's velocity as a person judges it: its motion over the last `span` s."""
        return (self.obstacle_seen(t) - self.obstacle_seen(t - span)) / span

    def keep(self) -> float:
        """Centre distance this person keeps from the obstacle (touching + own clearance)."""
        return self.scenario.clearance + self.person.clearance

    def target(self, state) -> np.ndarray:
        """Where this person steers: the goal, or with an overshoot a point that far past it
        along the approach until the goal is passed (then back to the goal: the correction)."""
        goal = np.asarray(self.scenario.goal, float)
        offset = goal - np.asarray(state[:2], float)
        distance = float(np.hypot(*offset))
        if self.person.overshoot <= 0 or self.passed_goal:
            return goal
        if self.approach is None and distance < 1.0:
            self.approach = offset / max(distance, 1e-9)
        if self.approach is None:
            return goal
        if float(np.dot(offset, self.approach)) < -self.person.overshoot + 0.05:
            self.passed_goal = True
            return goal
        return goal + self.person.overshoot * self.approach

    def at_goal(self, state) -> bool:
        """Inside the goal region well enough to let go (after the correction, if overshooting)."""
        distance = float(np.hypot(*(np.asarray(self.scenario.goal, float) - state[:2])))
        inside = distance < 0.85 * self.scenario.goal_tolerance
        return inside and (self.person.overshoot <= 0 or self.passed_goal)

    def goal_speed(self, state, speed: float) -> float:
        """Slowing down for the goal: a person who brakes in time slows over the last 0.5 m;
        an overshooting person does not (and corrects at half speed after passing)."""
        distance = float(np.hypot(*(np.asarray(self.scenario.goal, float) - state[:2])))
        if self.person.overshoot > 0:
            return 0.5 * speed if self.passed_goal else speed
        return speed * min(1.0, max(0.35, distance / 0.5))

    # --- the hand ------------------------------------------------------------------------------
    def axes(self, state, t: float) -> List[float]:
        """The stick this person holds now (sensor_msgs/Joy axes)."""
        if self.scenario is None:
            raise LfdError(f"{type(self).__name__}: reset(scenario) before driving")
        state = np.asarray(state, float)
        if self.at_goal(state):
            wanted, self.residual = np.zeros(2), np.zeros(2)
        else:
            speed, turn = self.intent(state, float(t))
            # people learn how the robot answers the stick: they push for the speed they want
            limit = self.scenario.limits.v_max
            speed = float(saturate_inverse(math.copysign(min(abs(speed), 0.95 * limit), speed), limit))
            wanted = np.array([speed / self.mapping.scale_linear, turn / self.mapping.scale_angular])
            wanted = np.clip(wanted, -1.0, 1.0)
        stick = np.zeros(2)
        if np.any(wanted):
            for i in (0, 1):        # error diffusion: the average stick is what the person wants
                stick[i] = quantise(wanted[i] + self.residual[i], self.person.levels)
                self.residual[i] = float(np.clip(wanted[i] + self.residual[i] - stick[i], -0.5, 0.5))
            stick = stick + self.person.noise * self.rng.standard_normal(2)
        self.pending.append((float(np.clip(stick[0], -1, 1)), float(np.clip(stick[1], -1, 1))))
        linear, angular = self.pending.popleft()
        axes = [0.0] * 8
        mapping = self.mapping
        for index, fraction in ((mapping.axis_linear, linear), (mapping.axis_angular, angular)):
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

    # --- whole drives ------------------------------------------------------------------------
    def drive(self, scenario: Scenario, start, *, execution_noise=(0.0, 0.0)):
        """One drive: (actions (T, 2), states x_1..x_T, reached, collided, idle steps).
        execution_noise (std of v_cmd, w_cmd) perturbs what the robot executes while `actions`
        keep the person's own commands (DART data)."""
        self.reset(scenario)
        model = scenario.model()
        state = np.asarray(start, float)
        actions, states = [], []
        reached = collided = False
        idle = 0
        for k in range(int(round(scenario.max_time / scenario.dt))):
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
            idle = idle + 1 if inside and not np.any(action) else 0
            if idle >= self.person.idle_steps:
                break
        return np.array(actions), np.array(states), reached and not collided, collided, idle

    def describe(self) -> Dict:
        return {"family": self.family, **{k: (round(v, 4) if isinstance(v, float) else v)
                                          for k, v in vars(self.person).items()}}

    def demonstrate(self, scenario: Scenario, start) -> Demonstration:
        actions, states, reached, collided, idle = self.drive(scenario, start)
        return Demonstration(scenario, start, actions, 0.0, states, source=f"person:{self.family}",
                             meta=dict(self.describe(), reached=bool(reached), collided=bool(collided),
                                       idle_steps=int(idle)))

    def success(self, scenario: Scenario, start) -> Dict:
        """{reached, collided, success, time, mean_speed, closest} of one drive: this person's own
        figures (time to the goal region, mean speed until then, closest approach to the
        obstacle beyond touching)."""
        actions, states, reached, collided, _ = self.drive(scenario, start)
        return drive_figures(scenario, np.vstack([start, states]), reached, collided)


def drive_figures(scenario: Scenario, trajectory, reached: bool, collided: bool) -> Dict:
    """Success, time to the goal region, mean speed until then and closest approach (m beyond
    touching) of a trajectory x_0..x_T sampled every scenario.dt."""
    trajectory = np.asarray(trajectory, float)
    times = scenario.dt * np.arange(len(trajectory))
    inside = np.flatnonzero(scenario.reached(trajectory))
    end = int(inside[0]) if len(inside) else len(trajectory) - 1
    path = np.sum(np.hypot(*np.diff(trajectory[:end + 1, :2], axis=0).T)) if end else 0.0
    closest = scenario.obstacle_distance(trajectory[:end + 1], times[:end + 1]) - scenario.clearance
    return {"reached": bool(reached), "collided": bool(collided), "success": bool(reached and not collided),
            "time": float(times[end]) if len(inside) else float("nan"),
            "mean_speed": float(path / max(times[end], scenario.dt)), "closest": float(closest.min())}
