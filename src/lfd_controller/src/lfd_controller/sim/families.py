"""Demonstrator families: six structurally different ways a person could drive (no ROS).

Each family is its own policy (what the person wants from what they see); the hand, the stick,
the reaction delay and the per-person variation are shared (sim.person). None of them optimises
the learner's features:

  * `TangentSwerveDriver` - reactive: heads for the goal, and when the (extrapolated) obstacle is
    in the way swerves to the tangent of a circle around it, slowing near it;
  * `PotentialFieldDriver` - reactive steering in a potential field: attraction to the goal,
    repulsion from the obstacle a short look-ahead ahead, a swirl around it on the person's side;
  * `PursuitVODriver` - pure pursuit of the goal with velocity-obstacle avoidance: the heading
    closest to the goal whose relative velocity does not hit the obstacle within a few seconds;
  * `SocialForceDriver` - a walker (Helbing's social force): a desired velocity relaxed toward the
    goal plus an anisotropic exponential push away from the obstacle; the robot follows it;
  * `SamplingMPCDriver` - a sampling planner with its own cost: constant-arc rollouts of a plain
    kinematic model, scored on the distance left to the goal, a clearance hinge and the person's
    speed; the best arc's first command;
  * `YieldingDriver` - waits for the way to clear: a velocity-obstacle test of headings near the
    goal's from a delayed estimate of the obstacle (where it was 0.2-0.5 s ago, moving as it did
    then); a moving obstacle in the way is let pass (stop and wait, backing off only when it
    would hit the person standing), a static one is driven round.

`FAMILIES` maps each family's name to its class; `make_person(family, seed)` draws a person.
"""
import math
from typing import Dict, Type

import numpy as np

from lfd_controller.errors import LfdError
from lfd_controller.sim.person import SimulatedPerson, wrap


def _steer(person, state, heading: float, speed: float):
    """(speed, turn): turn toward `heading`, slow while facing away from it."""
    error = wrap(heading - state[2])
    return speed * max(0.0, math.cos(error)) ** 2, person.today.turn_gain * error


class TangentSwerveDriver(SimulatedPerson):
    """Heads for the goal; swerves to the tangent of a circle of the person's clearance around
    where the obstacle will be (extrapolated over a look-ahead), from a trigger distance on."""

    family = "tangent"

    def start_drive(self):
        rng = self.rng
        self.lookahead = rng.uniform(0.6, 1.5)
        self.trigger = self.keep() + rng.uniform(0.5, 1.1)
        self.slow_near = rng.uniform(0.5, 0.95)
        self.side = None

    def intent(self, state, t):
        px, py, yaw, v = state[:4]
        target = self.target(state)
        to_goal = target - (px, py)
        goal_dist = float(np.hypot(*to_goal))
        goal_bearing = math.atan2(to_goal[1], to_goal[0])
        now = self.obstacle_seen(t)
        velocity = self.obstacle_velocity(t)
        reach = min(self.lookahead, float(np.hypot(*(now - (px, py)))) / max(abs(v), 0.25))
        to_obst = now + reach * velocity - (px, py)
        obst_dist = float(np.hypot(*to_obst))
        obst_bearing = math.atan2(to_obst[1], to_obst[0])
        keep, relative = self.keep(), wrap(obst_bearing - goal_bearing)
        in_way = (obst_dist < goal_dist + keep and abs(relative) < math.pi / 2
                  and abs(obst_dist * math.sin(relative)) < keep)
        heading = goal_bearing
        if obst_dist < self.trigger and (in_way or self.side is not None) and obst_dist > keep * 0.5:
            if self.side is None:
                lateral = -math.sin(goal_bearing) * velocity[0] + math.cos(goal_bearing) * velocity[1]
                if abs(lateral) > 0.05:          # pass behind a crossing obstacle
                    self.side = -1.0 if lateral > 0 else 1.0
                elif abs(relative) > 0.1:        # away from its offset
                    self.side = -1.0 if relative > 0 else 1.0
                else:
                    self.side = self.person.side
            half = math.asin(min(1.0, keep / obst_dist))
            tangent = obst_bearing + self.side * half
            if self.side * wrap(goal_bearing - tangent) < 0:
                heading = tangent
            if not in_way and abs(relative) > half + 0.3:
                self.side = None
        elif obst_dist >= self.trigger:
            self.side = None
        speed = self.goal_speed(state, self.today.speed)
        if obst_dist < self.trigger:
            closeness = 1.0 - max(0.0, obst_dist - keep) / max(self.trigger - keep, 1e-6)
            speed *= 1.0 - (1.0 - self.slow_near) * min(1.0, max(0.0, closeness))
        return _steer(self, state, heading, speed)


class PotentialFieldDriver(SimulatedPerson):
    """Steers along attraction to the goal plus repulsion from the obstacle seen a short look-ahead
    ahead (0.2-1.2 s), with a swirl around it to the person's side (no local minimum in front)."""

    family = "potential"

    def start_drive(self):
        self.lookahead = self.rng.uniform(0.2, 1.2)
        self.gain = self.rng.uniform(0.3, 0.8)
        self.swirl = self.rng.uniform(0.6, 1.2)
        self.influence = self.rng.uniform(0.5, 0.9)

    def intent(self, state, t):
        position = state[:2]
        to_goal = self.target(state) - position
        pull = to_goal / max(float(np.hypot(*to_goal)), 1e-9)
        velocity = self.obstacle_velocity(t)
        push, nearest = np.zeros(2), np.inf
        for ahead in (0.0, 0.5 * self.lookahead, self.lookahead):   # where it is and will be
            away = position - (self.obstacle_seen(t) + ahead * velocity)
            centre = max(float(np.hypot(*away)), 1e-9)
            gap = max(centre - self.keep() + 0.1, 0.02)              # beyond the person's room
            nearest = min(nearest, gap)
            if gap < self.influence:
                unit = away / centre
                strength = self.gain * (1.0 / gap - 1.0 / self.influence)
                side = self.person.side                               # +1: pass on the left
                offset = pull[0] * unit[1] - pull[1] * unit[0]
                if abs(offset) > 0.2:
                    side = 1.0 if offset > 0 else -1.0               # swirl the short way round
                push += strength * (unit + self.swirl * side * np.array([unit[1], -unit[0]]))
        direction = pull + push
        speed = self.goal_speed(state, self.today.speed)
        speed *= min(1.0, max(0.3, nearest / 0.4))
        return _steer(self, state, math.atan2(direction[1], direction[0]), speed)


class PursuitVODriver(SimulatedPerson):
    """Pure pursuit of the goal (turn rate 2 v sin(alpha) / look-ahead distance) along the admissible
    heading closest to it: a heading is admissible when the velocity relative to the obstacle does
    not enter a disc of the person's clearance within a time horizon (velocity obstacle); ties go
    to the person's side, and with no admissible heading the person slows, then stops and turns."""

    family = "pursuit_vo"
    OFFSETS = np.radians(np.arange(-90, 91, 10))

    def start_drive(self):
        self.lookahead = self.rng.uniform(0.5, 1.0)
        self.horizon = self.rng.uniform(2.0, 4.0)

    def admissible(self, position, velocity_obs, obstacle, headings, speed):
        relative = speed * np.stack([np.cos(headings), np.sin(headings)], axis=1) - velocity_obs
        offset = obstacle - position
        along = relative @ offset
        rel2 = np.maximum(np.sum(relative ** 2, axis=1), 1e-9)
        when = np.clip(along / rel2, 0.0, self.horizon)
        closest = np.hypot(*(offset[None, :] - when[:, None] * relative).T)
        # already inside the clearance: any heading that does not bring it closer will do
        return closest > min(self.keep(), float(np.hypot(*offset)) - 0.01)

    def intent(self, state, t):
        position, yaw = state[:2], state[2]
        to_goal = self.target(state) - position
        goal_bearing = math.atan2(to_goal[1], to_goal[0])
        obstacle, velocity_obs = self.obstacle_seen(t), self.obstacle_velocity(t)
        headings = goal_bearing + self.OFFSETS
        cost = np.abs(self.OFFSETS) - 0.05 * self.person.side * np.sign(self.OFFSETS)
        speed = self.goal_speed(state, self.today.speed)
        for factor in (1.0, 0.6, 0.3):
            ok = self.admissible(position, velocity_obs, obstacle, headings, speed * factor)
            if np.any(ok):
                heading = float(headings[np.flatnonzero(ok)[np.argmin(cost[ok])]])
                speed *= factor
                break
        else:
            away = position - obstacle
            heading, speed = math.atan2(away[1], away[0]) + self.person.side * math.pi / 2, 0.0
        alpha = wrap(heading - yaw)
        forward = speed * max(0.0, math.cos(alpha))
        turn = 2.0 * max(forward, 0.15) * math.sin(alpha) / self.lookahead
        if abs(alpha) > math.pi / 2:
            turn = math.copysign(self.today.turn_gain, alpha)
        return forward, turn


class SocialForceDriver(SimulatedPerson):
    """A walker: the desired velocity u relaxes toward the person's speed at the goal with a time
    constant tau, pushed by A exp((R - d) / B) away from the obstacle (weighted by lambda + (1 -
    lambda)(1 + cos phi) / 2 for what lies ahead) and sideways to the person's side; the robot
    heads along u at |u|."""

    family = "social_force"

    def start_drive(self):
        rng = self.rng
        self.tau = rng.uniform(0.4, 1.0)
        self.strength = rng.uniform(1.0, 2.5)
        self.range = rng.uniform(0.15, 0.35)
        self.anisotropy = rng.uniform(0.2, 0.6)
        self.velocity = None

    def intent(self, state, t):
        dt = self.scenario.dt
        position, yaw = state[:2], state[2]
        if self.velocity is None:
            self.velocity = 0.05 * np.array([math.cos(yaw), math.sin(yaw)])
        to_goal = self.target(state) - position
        desired = self.goal_speed(state, self.today.speed) * to_goal / max(float(np.hypot(*to_goal)), 1e-9)
        force = (desired - self.velocity) / self.tau
        away = position - (self.obstacle_seen(t) + 0.5 * self.obstacle_velocity(t))
        centre = max(float(np.hypot(*away)), 1e-9)
        unit = away / centre
        heading_unit = self.velocity / max(float(np.hypot(*self.velocity)), 1e-9)
        ahead = self.anisotropy + (1 - self.anisotropy) * (1 - float(heading_unit @ unit)) / 2
        magnitude = self.strength * ahead * math.exp((self.keep() - centre) / self.range)
        side = self.person.side
        goal_unit = to_goal / max(float(np.hypot(*to_goal)), 1e-9)
        offset = goal_unit[0] * unit[1] - goal_unit[1] * unit[0]
        if abs(offset) > 0.2:
            side = 1.0 if offset > 0 else -1.0               # round the short way
        sideways = side * np.array([unit[1], -unit[0]])     # side +1: pass on the left
        force = force + magnitude * (unit + sideways)
        self.velocity = self.velocity + dt * force
        cap = 1.2 * self.today.speed
        norm = float(np.hypot(*self.velocity))
        if norm > cap:
            self.velocity *= cap / norm
        heading = math.atan2(self.velocity[1], self.velocity[0])
        return _steer(self, state, heading, float(np.hypot(*self.velocity)))


class SamplingMPCDriver(SimulatedPerson):
    """Samples constant-arc commands (speeds 0..preferred, turn rates -2..2 rad/s) over a 1.6-3 s
    horizon of a plain kinematic unicycle (no acceleration limits), with the obstacle moving at
    its seen velocity, and keeps the best under its own cost: distance left to the goal, a squared
    hinge inside the person's clearance (a large cost for touching), the gap to the person's
    speed, and a little for turning and for changing its mind."""

    family = "sampling_mpc"

    def start_drive(self):
        rng = self.rng
        self.horizon = rng.uniform(1.6, 3.0)
        self.clear_weight = rng.uniform(20.0, 60.0)
        self.previous = None

    def intent(self, state, t):
        speed = self.goal_speed(state, self.today.speed)
        speeds = np.linspace(0.0, speed, 5)
        turns = np.linspace(-2.0, 2.0, 11)
        v, w = (grid.reshape(-1) for grid in np.meshgrid(speeds, turns))
        step = 0.2
        count = int(self.horizon / step)
        times = step * np.arange(1, count + 1)
        yaw = state[2] + w[:, None] * times[None, :]
        x = state[0] + np.cumsum(v[:, None] * np.cos(yaw) * step, axis=1)
        y = state[1] + np.cumsum(v[:, None] * np.sin(yaw) * step, axis=1)
        target = self.target(state)
        left = np.hypot(x - target[0], y - target[1])
        obstacle = self.obstacle_seen(t)[None, :] + times[:, None] * self.obstacle_velocity(t)[None, :]
        gap = np.hypot(x - obstacle[None, :, 0], y - obstacle[None, :, 1])
        inside = np.maximum(self.keep() - gap, 0.0)
        cost = (left.min(axis=1) + 0.5 * left[:, -1] + self.clear_weight * np.sum(inside ** 2, axis=1)
                + 1000.0 * np.any(gap < self.scenario.clearance, axis=1)
                + 0.5 * (v - speed) ** 2 / max(speed, 0.1) + 0.02 * w ** 2)
        if self.previous is not None:
            cost += 0.05 * np.hypot(v - self.previous[0], 0.2 * (w - self.previous[1]))
        cost -= 0.01 * self.person.side * np.sign(w)
        best = int(np.argmin(cost))
        self.previous = (v[best], w[best])
        return float(v[best]), float(w[best])


class YieldingDriver(SimulatedPerson):
    """Yields to a moving obstacle: drives at the goal along the admissible heading within
    `detour` of it (velocity-obstacle test over a 2-4 s horizon with the person's clearance plus
    a little more, from a delayed estimate - the obstacle where it was `estimate_delay` s ago,
    moving as it did then); when a moving obstacle blocks every such heading the person stops
    and waits facing the goal until the way is clear (or, when standing would be hit, steps
    away from it). A static obstacle (judged slower than 0.05 m/s) is driven round."""

    family = "yield_vo"
    OFFSETS = np.radians(np.arange(-90, 91, 10))

    def start_drive(self):
        rng = self.rng
        self.horizon = rng.uniform(2.0, 4.0)
        self.estimate_delay = rng.uniform(0.2, 0.5)
        self.detour = math.radians(rng.uniform(20.0, 40.0))
        self.spare = rng.uniform(0.05, 0.15)
        self.lookahead = rng.uniform(0.5, 1.0)

    def clear(self, position, velocity_obs, obstacle, velocities):
        """Which of the robot velocities (n, 2) keep out of the person's room (plus spare)
        within the horizon, the obstacle moving at velocity_obs from `obstacle`."""
        relative = velocities - velocity_obs
        offset = obstacle - position
        rel2 = np.maximum(np.sum(relative ** 2, axis=1), 1e-9)
        when = np.clip(relative @ offset / rel2, 0.0, self.horizon)
        closest = np.hypot(*(offset[None, :] - when[:, None] * relative).T)
        return closest > min(self.keep() + self.spare, float(np.hypot(*offset)) - 0.01)

    def intent(self, state, t):
        position, yaw = state[:2], state[2]
        to_goal = self.target(state) - position
        goal_bearing = math.atan2(to_goal[1], to_goal[0])
        seen = t - self.estimate_delay                  # the delayed estimate
        obstacle, velocity_obs = self.obstacle_seen(seen), self.obstacle_velocity(seen)
        moving = float(np.hypot(*velocity_obs)) > 0.05
        offsets = self.OFFSETS[np.abs(self.OFFSETS) <= self.detour] if moving else self.OFFSETS
        headings = goal_bearing + offsets
        cost = np.abs(offsets) - 0.05 * self.person.side * np.sign(offsets)
        speed = self.goal_speed(state, self.today.speed)
        unit = np.stack([np.cos(headings), np.sin(headings)], axis=1)
        ok = self.clear(position, velocity_obs, obstacle, speed * unit)
        if np.any(ok):
            heading = float(headings[np.flatnonzero(ok)[np.argmin(cost[ok])]])
        elif not moving or self.clear(position, velocity_obs, obstacle, np.zeros((1, 2)))[0]:
            heading, speed = goal_bearing, 0.0          # wait for the way to clear
        else:                                           # it would hit me standing: step aside
            away = position - obstacle
            side = -velocity_obs if float(np.hypot(*away)) < 1e-9 else away
            heading = math.atan2(side[1], side[0])
        alpha = wrap(heading - yaw)
        forward = speed * max(0.0, math.cos(alpha)) ** 2
        turn = self.today.turn_gain * alpha
        if speed > 0:
            turn = 2.0 * max(forward, 0.15) * math.sin(alpha) / self.lookahead
            if abs(alpha) > math.pi / 2:
                turn = math.copysign(self.today.turn_gain, alpha)
        return forward, turn


FAMILIES: Dict[str, Type[SimulatedPerson]] = {
    cls.family: cls for cls in (TangentSwerveDriver, PotentialFieldDriver, PursuitVODriver,
                                SocialForceDriver, SamplingMPCDriver, YieldingDriver)}


def make_person(family: str, random_state=None, person=None, **kwargs) -> SimulatedPerson:
    """A simulated person of `family` (a new random Person unless `person` is given)."""
    if family not in FAMILIES:
        raise LfdError(f"unknown demonstrator family {family!r}; known: {sorted(FAMILIES)}")
    return FAMILIES[family](person, random_state, **kwargs)
