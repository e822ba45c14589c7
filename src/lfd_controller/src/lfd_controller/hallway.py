"""Following a path through a building among people with a learned reward (no ROS).

`HallwayController` is what reward_controller runs in path mode: each cycle it moves its local
waypoint along the path (`PathFollower`), builds a `HallwayTask` from the scan and the tracked
people, plans with the reward plus a fixed barrier around every scan point and person
(`HallwayBarrier`: the demonstrations never show what touching costs) and returns the first
command - or, when moving on would bring the scan inside its safety margin, a zero speed
(turning in place: a round robot touches nothing that way), saying why
(`status_`). A waypoint far off its heading on a new path, or after a recovery, is first turned
to in place. A robot held up (without 0.3 m of progress along the path) for `replan_after`
seconds follows a detour planned on the floor map and the scan (detour.plan_detour) round what
the path's planner never saw, and held up again first backs up; with a map, it plans that
detour at once when the scan shows something the map lacks (not a tracked person) on the path
just ahead; standing still for
`blocked_after` seconds, or held up for 3 x as long, it reports the path blocked and stays
stopped. Learning (`fit_hallway_reward`) is CIOC over the same tasks, built from the
demonstrations' own scans and tracked people at the start of each 4 s window, then an
acceptance check with the controller in the loop (`hallway_acceptance`): refused only where
the controller fails where the person succeeded.
"""
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from lfd_controller.cioc import LinearCIOC
from lfd_controller.demos import Demonstration
from lfd_controller.detour import plan_detour, plan_give_way
from lfd_controller.errors import LfdError
from lfd_controller.give_way import GIVE_WAY_ROOMS, MOVES, GivingWay, people_holding, ways_on
from lfd_controller.hallway_features import (
    HALLWAY_SIGNS,
    PERSON_RETURNS,
    HallwayFeatures,
    HallwayTask,
    PathFollower,
    in_sight,
    near_people,
    scan_points,
)
from lfd_controller.laplace import DemoDynamics
from lfd_controller.planner import RecedingHorizonController
from lfd_controller.rewards import RewardDerivatives
from robot_common.maps import GridMap, unmapped
from robot_common.polylines import nearest_arc, points_along, same_way
from robot_common.tasks import ObstacleMotion, Scenario

__all__ = ["HALLWAY_DRIVING", "HALLWAY_SAFETY", "room_margin", "TaskBuilder", "HallwayBarrier",
           "HallwayController",
           "HallwayDemonstration",
           "HallwayCIOC", "hallway_scenario", "fit_hallway_reward", "hallway_windows",
           "task_from_view"]

# How the controller drives a hallway reward: 12 steps of 0.4 s (4.8 s look-ahead, the people's
# constant-velocity prediction is not worth more), warm start + one turning or detour seed per
# cycle (detours 0.9 m beside what blocks the way to the waypoint; after 2 s standing in front
# of something static, a detour past it: planner.RecedingHorizonController's unstall),
# discount 0.97, a barrier 0.1 m beyond touching a person or a scan point (a taught reward brings
# the person's own room to people; walls and clutter keep 0.1 m: the person's room to people is
# no room to a door frame, and a barrier wider than half a narrow door's spare width held the
# planner before it), a safety stop (zero speed; turning in place
# allowed) when moving on would bring the scan within 0.05 m of the robot's edge, the path
# reported blocked after 20 s standing still or 60 s held up (without 0.3 m of progress), a
# detour after 4 s held up and backing up the next time, a detour at once round something the map
# lacks within the detour's room of the path's next 2.5 m,
# the local waypoint 4 m ahead on the path or the furthest point up to there in the scan's sight,
# tracked people hiding nothing (further than a 4 s window
# or the look-ahead travels: a waypoint passed inside a window turns its progress feature around);
# on the last stretch, the goal in sight, the waypoint 4 m away through the goal (TaskBuilder).
HALLWAY_DRIVING = {"horizon": 12, "plan_dt": 0.4, "terminal": 0.0, "spread_seeds": True,
                   "discount": 0.97, "max_iter": 12, "seed_turns": (0.0, 1.0, -1.0),
                   "detour": 0.9, "unstall": 2.0}
HALLWAY_SAFETY = {"robot_radius": 0.18, "person_radius": 0.25, "barrier_margin": 0.1,
                  "wall_margin": 0.1, "stop_margin": 0.05, "blocked_after": 20.0, "lookahead": 4.0,
                  "replan_after": 4.0, "replan_ahead": 2.5, "give_way": True}
WINDOW, STRIDE = 40, 20
# The safety stop looks this far (m) along the command beyond the stopping distance, and lets
# through moves that bring a point inside its margin no more than this much (m) closer.
STOP_LOOK, STOP_SLACK = 0.05, 0.01
# A scan return within MAP_SLACK m of a wall of the floor map is the wall (a robot's pose is that
# far off the map); one further from every wall and from the tracked people is something the map
# lacks. The path ahead is checked every SCAN_EVERY s, a detour round it tried at most every
# AHEAD_EVERY s.
MAP_SLACK, AHEAD_EVERY = 0.2, 2.0
# Progress along the path (m) that counts as getting on (the detour and blocked clocks), and the
# detour's room: the safety stop's reach plus this much (m).
PROGRESS_STEP, DETOUR_ROOM = 0.3, 0.05
# Standing still for `blocked_after` s, or without PROGRESS_STEP m of progress for this many times
# as long (trying detours and backing up), the path is reported blocked.
PROGRESS_PATIENCE = 3.0
# Held up again after a detour, the robot first backs up BACKUP_SPEED m/s for BACKUP_TIME s when
# nothing is behind it (nav2's BackUp recovery): someone standing close in front - who may be
# waiting for the robot to make way - gets room to walk on.
BACKUP_SPEED, BACKUP_TIME = 0.15, 2.0
# On a new path and after a recovery (a detour or backing up), a robot whose local waypoint
# lies more than TURN_START rad off its heading first turns in place toward it, at up to
# TURN_RATE rad/s, until within TURN_DONE rad (nav2's rotation shim): a detour or a re-planned
# path often starts behind the robot, and the learned reward, facing a wall, pushed into it
# instead of turning round.
TURN_START, TURN_DONE, TURN_RATE = math.radians(60.0), math.radians(20.0), 1.0
# The scans a detour is planned on: one every SCAN_EVERY s over the last SCAN_MEMORY s (what the
# robot saw on its way in: a cart hides what is behind it from where the robot stands).
SCAN_EVERY, SCAN_MEMORY = 0.5, 10.0
# The tracked people kept as often, for this long (s): who walked up to the robot and stopped
# (give_way.people_holding).
PEOPLE_MEMORY = 12.0
# Share of the cycle budget, counted from the cycle's start (the task from the scan and people
# included), after which the planner starts nothing new; the rest is headroom for a busy machine
# (on 2 shared cores a cycle can lose tens of ms to other processes).
PLANNING_SHARE = 0.6
# A re-plan keeps to the way being driven when, over the look-ahead from the robot, it stays
# within this much (m) of the old path (plus however far the robot is off it): a planner's
# re-plans of one route differ by a cell or two, or by a swerve round someone in the hall.
ROUTE_TOLERANCE = 0.5


def hallway_scenario(dt: float = 0.1, name: str = "hallway") -> Scenario:
    """The Scenario a hallway demonstration carries: the robot's limits and time step (its goal
    and obstacle are unused: each window has its own HallwayTask)."""
    return Scenario(name, np.zeros(2), ObstacleMotion(0.0, 0.0, 0.1), dt=dt,
                    bounds=(-1e4, -1e4, 1e4, 1e4))


def laser_pose(pose, offset: float):
    """(x, y, yaw) of a laser `offset` m ahead of the base at `pose` (x, y, yaw, ...)."""
    x, y, yaw = (float(v) for v in pose[:3])
    return x + offset * math.cos(yaw), y + offset * math.sin(yaw), yaw


def task_from_view(waypoint, goal, pose, angles, ranges, people, velocities, now: float,
                   laser_offset: float = 0.0) -> HallwayTask:
    """The planning instant's HallwayTask from the robot's pose (x, y, yaw), its scan (angles in
    the laser frame, `laser_offset` m ahead of the base) and the tracked people (map frame)."""
    laser = laser_pose(pose, laser_offset)
    people = np.asarray(people, float).reshape(-1, 2)
    points = scan_points(laser, angles, ranges, people=people)
    return HallwayTask(waypoint, goal, points, people, np.asarray(velocities, float).reshape(-1, 2),
                       now, robot=np.array(pose[:2], float))


class TaskBuilder:
    """The HallwayTask of each cycle along one path: the local waypoint (PathFollower, in the
    scan's sight) and task_from_view. What the controller, the recorded demonstrations and the
    benchmark's baselines all plan with.

    `through_goal` (the controller's arrival): once the waypoint is the path's end and the goal
    is in sight, the waypoint is `lookahead` m from the robot through the goal, so the pull
    toward it keeps its strength to the end (the progress feature fades within its softening
    of the waypoint: next to a wall the robot settled a few cm outside the goal tolerance)
    and the controller stops inside the tolerance. Demonstrations keep the plain waypoint: the
    person slows down for the goal."""

    def __init__(self, path, *, lookahead: float = 4.0, laser_offset: float = 0.0,
                 through_goal: bool = False):
        self.follower = PathFollower(path, lookahead=lookahead)
        self.laser_offset = float(laser_offset)
        self.through_goal = bool(through_goal)

    @property
    def goal(self) -> np.ndarray:
        return self.follower.path[-1]

    def __call__(self, state, t: float, angles, ranges, people, velocities) -> HallwayTask:
        laser = laser_pose(state, self.laser_offset)
        visible = in_sight(laser, angles, ranges, people=people)
        waypoint = self.follower.update(state[:2], visible)
        if self.through_goal and np.allclose(waypoint, self.goal) and visible(self.goal):
            offset = self.goal - np.asarray(state[:2], float)
            distance = float(np.hypot(*offset))
            if distance > 1e-6:
                waypoint = np.asarray(state[:2], float) + offset * (
                    max(distance, self.follower.lookahead) / distance)
        return task_from_view(waypoint, self.goal, state, angles, ranges, people, velocities, t,
                              self.laser_offset)


class HallwayBarrier:
    """A reward plus -scale ((r + m - d) / m)^2 for each predicted person (r: both radii, m:
    `margin`) and each scan point (r: the robot's radius, m: `wall_margin`) closer than r + m
    (planning only)."""

    def __init__(self, reward, *, robot_radius: float, person_radius: float, margin: float,
                 wall_margin: float, scale: Optional[float] = None):
        self.reward, self.margin, self.wall_margin = reward, float(margin), float(wall_margin)
        self.robot_radius, self.person_radius = float(robot_radius), float(person_radius)
        self.scale = float(scale if scale is not None else 10.0 * np.max(np.abs(reward.weights)))

    def derivatives(self, states, actions, times, task: HallwayTask, *, order: int = 1):
        if order > 1:
            raise LfdError("HallwayBarrier gives first derivatives only (for planning)")
        rd = self.reward.derivatives(states, actions, times, task, order=order)
        states = np.atleast_2d(np.asarray(states, float))
        value, rx = rd.value.copy(), rd.rx.copy()
        groups = [(task.points[None], self.robot_radius, self.wall_margin)]
        if len(task.people):
            groups.append((task.people_at(times), self.robot_radius + self.person_radius,
                           self.margin))
        for centres, reach, margin in groups:
            if centres.shape[1] == 0:
                continue
            offset = states[:, None, :2] - centres
            distance = np.sqrt(np.maximum((offset ** 2).sum(axis=2), 1e-18))
            depth = np.maximum(reach + margin - distance, 0.0) / margin
            if not depth.any():
                continue
            value -= self.scale * (depth ** 2).sum(axis=1)
            pull = (2.0 * self.scale * depth / margin / distance)[..., None] * offset
            rx[:, :2] += pull.sum(axis=1)
        return RewardDerivatives(value, rx, rd.ru)


@dataclass
class HallwayController:
    """Path following with a learned hallway reward (module docstring). `act(state, t, angles,
    ranges, people, velocities)` -> command; `status_` is "following", "arrived", "stopped: ..."
    or "blocked: ..."; `cycle_times_` the cycle times (the task and the planning)."""

    reward: object
    path: np.ndarray
    model: object
    budget: Optional[float] = 0.1
    goal_tolerance: float = 0.3
    laser_offset: float = 0.0
    settings: Dict = field(default_factory=lambda: dict(HALLWAY_DRIVING))
    safety: Dict = field(default_factory=lambda: dict(HALLWAY_SAFETY))
    grid: Optional[GridMap] = None

    def __post_init__(self):
        planned = HallwayBarrier(self.reward, robot_radius=self.safety["robot_radius"],
                                 person_radius=self.safety["person_radius"],
                                 margin=self.safety["barrier_margin"],
                                 wall_margin=self.safety["wall_margin"])
        budget = None if self.budget is None else PLANNING_SHARE * self.budget
        self.planner = RecedingHorizonController(planned, self.model, budget=budget,
                                                 **self.settings)
        self.detours_ = self.backups_ = self.give_ways_ = 0
        self._scans, self._scanned = deque(maxlen=int(SCAN_MEMORY / SCAN_EVERY)), -math.inf
        self._seen_people = deque(maxlen=int(PEOPLE_MEMORY / SCAN_EVERY))
        self._position, self._now = None, 0.0
        self.path = np.asarray(self.path, float).reshape(-1, 2)
        self._start(self.path)

    def new_path(self, path) -> bool:
        """Follow `path` (a re-plan to the same goal) from now on. A re-plan of the way being
        driven (robot_common.polylines.same_way: within ROUTE_TOLERANCE m over the look-ahead)
        only replaces the path: the progress and blocked clocks and a recovery under way go on
        (move_base re-plans every second or so; a robot held up must still get to its
        recoveries and report a blocked path), and a blocked robot stays stopped until it has
        been blocked `blocked_after` s. A route elsewhere starts as a new controller would
        (turning to it first), keeping what the robot saw (the scans and people that detours
        and giving way use) and its recovery counts. True when the way was kept."""
        path = np.asarray(path, float).reshape(-1, 2)
        kept = self._position is not None and same_way(
            self.path, path, self._position, ahead=self.safety["lookahead"],
            tolerance=ROUTE_TOLERANCE)
        retry = self.status_.startswith("blocked") and (
            self._now - self._blocked_at >= self.safety["blocked_after"])
        self.path = path
        if not kept or retry:
            self._start(path)
        elif not self._on_detour:       # a detour keeps going until it rejoins the same way
            self._follow(path)
            self.follower.progress = nearest_arc(path, self._position)[0]
            self._left = self.follower.length - self.follower.progress
            self._detour_until = -math.inf
        return kept and not retry

    def _follow(self, path) -> None:
        """Build each cycle's task, and the waypoint follower, along `path`."""
        self.task = TaskBuilder(path, lookahead=self.safety["lookahead"],
                                laser_offset=self.laser_offset, through_goal=True)
        self.follower = self.task.follower

    def _start(self, path) -> None:
        """Follow `path` from its start: the clocks start again and any recovery under way ends."""
        self._follow(path)
        self.status_, self.held_since_ = "following", None
        self._giving_way: Optional[GivingWay] = None
        self._left, self._getting_on, self._tried = math.inf, 0.0, 0.0
        self._recoveries, self._backing_until, self._turning = 0, -math.inf, True
        self._detour_until, self._blocked_at = -math.inf, math.inf
        self._ahead_tried = -math.inf
        self._held_by = np.empty((0, 2))     # where people stood who held it up, since it got on

    @property
    def goal(self) -> np.ndarray:
        return self.follower.path[-1]

    def _detour(self, state, t: float, angles, ranges, people, velocities, names=None) -> bool:
        """Keep the scans and the progress clocks; with each kept scan that shows something the
        map lacks on the path ahead (`_unmapped_ahead`), and after `replan_after` s without
        PROGRESS_STEP m of progress (and as often again while none comes), follow a detour
        (detour.plan_detour, on the floor map and the scans) or, every other time held up, back
        up first. True when the path changed."""
        laser = laser_pose(state, self.laser_offset)
        if t - self._scanned >= SCAN_EVERY:
            self._scans.append((laser, np.asarray(angles, float), np.asarray(ranges, float)))
            self._seen_people.append((np.asarray(people, float), np.asarray(velocities, float),
                                      None if names is None else list(names)))
            self._scanned = t
            if self._unmapped_ahead(laser, angles, ranges, people):
                self._ahead_tried = t
                if self._rejoin(state, list(self._scans), self._detour_clearance):
                    return True
        left = self.follower.length - self.follower.progress
        if left < self._left - PROGRESS_STEP:
            self._left, self._getting_on, self._tried = left, t, t
            self._recoveries, self._held_by = 0, np.empty((0, 2))
        wait = self.safety.get("replan_after", 0.0)
        if wait <= 0 or t - self._tried < wait:
            return False
        self._tried, self._recoveries = t, self._recoveries + 1
        scans = list(self._scans)[:-1] + [(laser, angles, ranges)]
        clearance = self._detour_clearance
        holding = people_holding(state, people, velocities, self._seen_people, names=names,
                                 held_by=self._held_by)
        if holding.any():
            self._held_by = np.vstack([self._held_by, np.asarray(people, float)[holding]])[-8:]
        if self.safety.get("give_way", True) and holding.any():    # someone waits for it
            spot = self._spot_aside(state, people, names, holding, scans)
            if spot is not None:
                self._giving_way = GivingWay(spot, np.array(state[:2], float), t)
                self.give_ways_ += 1
                return False
        if self._recoveries % 2 == 0:       # every other time held up: back up first
            self._backing_until, self.backups_ = t + BACKUP_TIME, self.backups_ + 1
            self._turning = True
            return False
        return self._rejoin(state, scans, clearance)

    def _unmapped_ahead(self, laser, angles, ranges, people) -> bool:
        """With a floor map, and AHEAD_EVERY s after the last try: whether a return of this scan
        that is no wall of the map (MAP_SLACK) and no tracked person lies within the detour's room
        of the path's next `replan_ahead` m (move_base would re-plan round it: its costmap has
        it)."""
        ahead = self.safety.get("replan_ahead", 0.0)
        if self.grid is None or ahead <= 0 or self._now - self._ahead_tried < AHEAD_EVERY:
            return False
        ranges, angles = np.asarray(ranges, float), np.asarray(angles, float)
        ok = np.isfinite(ranges) & (ranges > 0.01) & (ranges < ahead + 0.5)     # off the path
        bearings = laser[2] + angles[ok]
        points = np.column_stack([laser[0] + ranges[ok] * np.cos(bearings),
                                  laser[1] + ranges[ok] * np.sin(bearings)])
        # what already stands within the detour's room of the robot is the held-up recoveries'
        # (a detour from where it stands starts there whatever it plans)
        points = points[np.hypot(points[:, 0] - self._position[0], points[:, 1] - self._position[1])
                        >= self._detour_clearance]
        people = np.asarray(people, float).reshape(-1, 2)
        if len(people) and len(points):
            points = points[~near_people(points, people, PERSON_RETURNS)]
        lacked = unmapped(self.grid, points, MAP_SLACK)
        if not lacked.any():
            return False
        points = points[lacked]
        path = points_along(self.follower.path, self.follower.progress
                            + np.arange(0.0, ahead + 1e-9, 0.1), self.follower.arc)
        gaps = np.hypot(path[:, None, 0] - points[None, :, 0], path[:, None, 1] - points[None, :, 1])
        return bool(gaps.min() < self._detour_clearance)

    def _spot_aside(self, state, people, names, waiting, scans) -> Optional[np.ndarray]:
        """The way to a spot out of the way of the `waiting` (mask) of `people`
        (detour.plan_give_way, with the ways they walked by give_way.ways_on, keeping the first
        room of give_way.GIVE_WAY_ROOMS that has a spot), or None."""
        who = np.asarray(people, float).reshape(-1, 2)[waiting]
        ways = ways_on(who, self._seen_people,
                       names=None if names is None else np.asarray(names)[waiting])
        for aside, clear in GIVE_WAY_ROOMS:
            spot = plan_give_way(self.follower, state[:2], who, scans, ways=ways, aside=aside,
                                 clear=clear, clearance=self._detour_clearance, grid=self.grid)
            if spot is not None:
                return spot
        return None

    @property
    def _detour_clearance(self) -> float:
        """What detours and spots to give way at keep from the scan: the safety stop's reach
        plus DETOUR_ROOM."""
        return self.safety["robot_radius"] + self.safety["stop_margin"] + DETOUR_ROOM

    def _rejoin(self, state, scans, clearance: float) -> bool:
        """Follow a detour from where the robot is back to its path; True when found."""
        detour = plan_detour(self.follower, state[:2], scans, clearance=clearance, grid=self.grid)
        if detour is None:
            return False
        self.task.follower = self.follower = PathFollower(
            detour.path, lookahead=self.follower.lookahead, closely=detour.rejoins)
        self._left, self.detours_ = self.follower.length, self.detours_ + 1
        self._turning, self._detour_until = True, detour.rejoins
        return True

    @property
    def _on_detour(self) -> bool:
        """On a detour's own stretch, before it rejoins the path."""
        return self.follower.progress < self._detour_until

    @property
    def cycle_times_(self) -> List[float]:
        return self.planner.cycle_times_

    def act(self, state, t: float, angles, ranges, people, velocities,
            names: Optional[Sequence[str]] = None) -> np.ndarray:
        """The command at `state` (x, y, yaw, v, w), time `t` (s), from the scan (angles in the
        laser frame, ranges) and the tracked people (map frame; `names`: their track names,
        "" untracked, when the tracker gives them)."""
        state = np.asarray(state, float)
        self._position, self._now = state[:2].copy(), float(t)
        if np.hypot(*(self.goal - state[:2])) < self.goal_tolerance:
            self.status_ = "arrived"
            return np.zeros(2)
        if self.status_.startswith("blocked"):
            return np.zeros(2)
        started = time.perf_counter()
        task = self.task(state, t, angles, ranges, people, velocities)
        if self._giving_way is None and self._detour(state, t, angles, ranges, people, velocities,
                                                     names):
            task = self.task(state, t, angles, ranges, people, velocities)
        if t - self._getting_on >= PROGRESS_PATIENCE * self.safety["blocked_after"]:
            return self._blocked(t - self._getting_on)
        if self._giving_way is not None:
            command = self._give_way(state, t, angles, ranges, people, velocities, names)
            if command is not None:
                return command
            task = self.task(state, t, angles, ranges, people, velocities)
        if t < self._backing_until:
            command = np.array([-BACKUP_SPEED, 0.0])
            if self._too_close(angles, ranges, state[3], command) is None:
                self.held_since_, self.status_ = None, "backing up: held up"
                return command
            self._backing_until = -math.inf
        if self._turning:       # a new path or a detour behind the robot: face it first
            turn = self._turn_toward(state, t, task.waypoint)
            if turn is not None:
                return turn
        command = self.planner.act(state, t, task, started=started)
        reason = self._too_close(angles, ranges, state[3], command)
        moving = abs(state[3]) > 0.05 or abs(command[0]) > 0.05
        if reason is None and moving:
            self.held_since_, self.status_ = None, "following"
            return command
        self.held_since_ = t if self.held_since_ is None else self.held_since_
        if t - self.held_since_ >= self.safety["blocked_after"]:
            return self._blocked(t - self.held_since_)
        if reason is not None:      # no way on: it may still turn in place (round robot)
            self.status_ = f"stopped: {reason}"
            return np.array([0.0, float(command[1])])
        self.status_ = "waiting"
        return command

    def _give_way(self, state, t: float, angles, ranges, people, velocities,
                  names=None) -> Optional[np.ndarray]:
        """The command while giving way (the safety stop applies), or None once done: then
        back to the path by a detour from where the robot is. Still in someone's way at its
        spot (GivingWay.in_the_way), it moves on to another spot out of their way."""
        waiting = self._giving_way.in_the_way(state, t, people, velocities)
        if waiting.any():
            spot = self._spot_aside(state, people, names, waiting,
                                    self._scans_with(state, angles, ranges))
            if spot is None:        # nowhere else to go: it waits on where it is
                self._giving_way.moves = MOVES
            else:
                self._giving_way = GivingWay(spot, self._giving_way.held_at, t,
                                             moves=self._giving_way.moves + 1)
        command = self._giving_way.command(state, t, people)
        self._tried, self.held_since_ = t, None
        if command is None:
            self._giving_way = None
            self._rejoin(state, self._scans_with(state, angles, ranges), self._detour_clearance)
            self._turning = True
            return None
        if self._too_close(angles, ranges, state[3], command) is not None:
            command = np.array([0.0, float(command[1])])
        moving = self._giving_way.arrived is None
        self.status_ = ("giving way: to a spot out of the way" if moving
                        else "giving way: waiting for people to pass")
        return command

    def _scans_with(self, state, angles, ranges) -> List:
        """The kept scans and the scan of this cycle, oldest first (what detours and spots to
        give way at are planned on)."""
        return list(self._scans) + [(laser_pose(state, self.laser_offset), angles, ranges)]

    def _turn_toward(self, state, t: float, waypoint) -> Optional[np.ndarray]:
        """On a new path or after a recovery: the command turning in place toward `waypoint`
        while it is more than TURN_START (once started, TURN_DONE) rad off the heading, else
        None (and no more turning until the next recovery). Turning holds the recovery clock."""
        offset = np.asarray(waypoint, float) - state[:2]
        bearing = math.remainder(math.atan2(offset[1], offset[0]) - state[2], 2.0 * math.pi)
        limit = TURN_DONE if self.status_ == "turning to the path" else TURN_START
        if abs(bearing) <= limit:
            self._turning = False
            return None
        self._tried, self.held_since_ = t, None
        self.status_ = "turning to the path"
        return np.array([0.0, math.copysign(min(TURN_RATE, 2.0 * abs(bearing)), bearing)])

    def _blocked(self, held: float) -> np.ndarray:
        self._blocked_at = min(self._blocked_at, self._now)
        self.status_ = (f"blocked: held up {held:.0f} s at {self.follower.progress:.1f} of "
                        f"{self.follower.length:.1f} m ({self.detours_} detours, "
                        f"{self.backups_} backing up tried)")
        return np.zeros(2)

    def _too_close(self, angles, ranges, speed: float, command) -> Optional[str]:
        """Why the scan forbids the command, or None: moving straight on (the way of its speed
        for the distance it needs to stop - one cycle at its speed plus braking at the
        acceleration limit - and the way of its command for STOP_LOOK m) would bring a scan
        point within the safety margin of the robot's edge, and more than STOP_SLACK m closer
        than it is. Turning in place moves a round robot nowhere, and what is behind or beside
        does not hold it: moving away from someone who stands close is how it gets free."""
        ranges, angles = np.asarray(ranges, float), np.asarray(angles, float)
        limit = self.safety["robot_radius"] + self.safety["stop_margin"]
        finite = np.where(np.isfinite(ranges), ranges, np.inf)
        with np.errstate(invalid="ignore"):     # distances from the base (the laser is ahead)
            along = self.laser_offset + finite * np.cos(angles)
            lateral = np.abs(finite * np.sin(angles))
            distance = np.hypot(along, lateral)
        moving = abs(float(speed))
        stopping = moving * 0.1 + moving ** 2 / (2.0 * self.model.limits.a_max)
        closest = distance
        for velocity, stretch in ((float(speed), stopping + STOP_LOOK), (float(command[0]), STOP_LOOK)):
            if abs(velocity) > 0.01:
                ahead = np.sign(velocity) * along
                passing = np.where(ahead < stretch, lateral, np.hypot(ahead - stretch, lateral))
                closest = np.minimum(closest, np.where(ahead > 0.0, passing, distance))
        close = (closest < limit) & (distance - closest > STOP_SLACK)
        if not close.any():
            return None
        nearest = int(np.argmin(np.where(close, closest, np.inf)))
        return (f"scan {distance[nearest]:.2f} m at {math.degrees(angles[nearest]):.0f} deg, "
                f"{closest[nearest]:.2f} m ahead: inside the {limit:.2f} m safety margin")


@dataclass
class HallwayDemonstration(Demonstration):
    """A window of a hallway drive with the HallwayTask seen where it starts."""

    task: Optional[HallwayTask] = None


def hallway_windows(states, actions, tasks: Sequence[HallwayTask], *, dt: float = 0.1,
                    length: int = WINDOW, stride: int = STRIDE, source: str = "person"
                    ) -> List[HallwayDemonstration]:
    """A drive (states x_0..x_T, actions (T, 2), the task seen at each step) cut into windows of
    `length` steps every `stride`, each with the task seen where it starts (as the controller
    plans: from what it sees now)."""
    states, actions = np.asarray(states, float), np.asarray(actions, float)
    scenario = hallway_scenario(dt)
    pieces = []
    for first in range(0, max(1, len(actions) - length // 2), stride):
        last = min(len(actions), first + length)
        if last - first < max(2, length // 2):
            break
        pieces.append(HallwayDemonstration(scenario, states[first], actions[first:last],
                                           first * dt, states[first + 1:last + 1], source,
                                           {"window": [first, last]}, task=tasks[first]))
    return pieces


class HallwayCIOC(LinearCIOC):
    """LinearCIOC over HallwayFeatures, each window with its own task."""

    def __init__(self, **kwargs):
        kwargs.setdefault("signs", HALLWAY_SIGNS)
        kwargs.setdefault("action_noise", "learn")
        kwargs.setdefault("second_order", False)
        super().__init__(HallwayFeatures(), **kwargs)

    def initial_weights(self) -> np.ndarray:
        """LinearCIOC's start (effort -1) with the state weights' jitter 100 times smaller: sums
        over many close scan points have large Hessians, and a jitter of 0.01 can already make
        the start's Hessian indefinite."""
        weights = super().initial_weights()
        states = len(self.features.state_names)
        weights[:states] *= 0.01
        return weights

    def _terms(self, demos):
        from lfd_controller.cioc import feature_terms
        return [feature_terms(DemoDynamics(d.scenario.model(), d.start, d.actions, d.t0, d.task),
                              self.features, self.terminal, self.second_order) for d in demos]


def fit_hallway_reward(windows: Sequence[HallwayDemonstration], seed: int = 0):
    """(reward, learner): HallwayCIOC on the windows (one BLAS thread: small matrices)."""
    if not windows:
        raise LfdError("no hallway demonstration windows to learn from")
    learner = HallwayCIOC(random_state=seed)
    with threadpool_limits(1):
        learner.fit(list(windows))
    return learner.reward_, learner


def calibrate_pace(reward, person_speed: float):
    """The reward with its squared-speed penalties scaled so its preferred cruising speed
    (path_progress / (2 |speed penalties|)) is the person's median moving speed: the one scale
    the acceptance check sets (the pace is weakly identified by windows; README)."""
    named = dict(zip(reward.features.names, reward.weights))
    squared = named["speed_squared"] + named["speed_effort"]
    if not (named["path_progress"] > 0 and squared < 0 and person_speed > 0):
        return reward
    wanted = -named["path_progress"] / (2.0 * person_speed)
    weights = reward.weights.copy()
    for name in ("speed_squared", "speed_effort"):
        weights[reward.features.names.index(name)] *= wanted / squared
    return type(reward)(weights, reward.features)


def room_margin(closest: Sequence[float], *, least: float = 0.1) -> float:
    """The barrier margin (m beyond touching) that keeps a person's room: their median closest
    approach to people over their demonstrations less 0.05 m, at least `least` (the one-obstacle
    calibration's rule, acceptance.calibrate)."""
    finite = [c for c in closest if np.isfinite(c)]
    return float(max(least, np.median(finite) - 0.05)) if finite else least


def hallway_acceptance(person: Sequence[Dict], controller: Sequence[Dict]) -> Dict:
    """The verdict on the controller's drives against the person's on the same scenes (dicts
    with success, collision, time): refused only for failing where the person succeeded - fewer
    than 80 % of the person's successes, any collision, or a median time over 1.5 x the
    person's."""
    mine = [c for p, c in zip(person, controller) if p["success"]]
    failures = []
    if not mine:
        return {"accepted": True, "failures": [], "note": "the person never succeeded"}
    rate = sum(c["success"] for c in mine) / len(mine)
    if rate < 0.8:
        failures.append(f"reaches the goal in {rate:.0%} of the scenes the person did")
    if any(c.get("collision") for c in controller):
        failures.append("collides")
    times = [(c["time"], p["time"]) for p, c in zip(person, controller) if p["success"] and
             c["success"]]
    if times and np.median([a for a, _ in times]) > 1.5 * np.median([b for _, b in times]):
        failures.append("median time over 1.5 x the person's")
    return {"accepted": not failures, "failures": failures}
