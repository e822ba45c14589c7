"""Reward features for following a path through a building among people (no ROS).

What a real robot has: a path (move_base's global plan or the workspace's grid planner), its
laser scan and a people tracker. A `HallwayTask` is one planning instant's view of them: the
local waypoint on the path (`PathFollower`), the scan's nearest points (the minimum of each
sector: walls and things the map does not have) and the tracked people moving at their tracked
velocities. Features (`HallwayFeatures`), summed over any number of points and people so one
reward fits every count:

  * `waypoint_heading`, `path_progress` - facing the local waypoint, and v x that (progress along
    the path per step);
  * `wall_proximity`, `wall_proximity_0.5` - sum over scan points of exp(-d^2 / 2 w^2), w = 0.25 m
    and 0.5 m (clearance to walls and unknown obstacles);
  * `people_proximity`, `people_room` - the same over the people, w = 0.5 m and 1.0 m (a person's
    proximity, the room kept);
  * `people_predicted` - each person's proximity 1 s ahead (robot at its speed and heading, person
    at their velocity): a smooth predicted closest approach;
  * `speed_squared`, `turn_squared` and the command efforts `speed_effort`, `turn_effort`.

Derivatives come from the same forward-mode jets as the one-obstacle features (jets.py).
"""
import math
from dataclasses import dataclass, field
from typing import Callable, Dict, Optional

import numpy as np

from lfd_controller.errors import LfdError
from lfd_controller.features import FeatureValues, as_trajectory
from lfd_controller.jets import Jet
from robot_common.polylines import arc_lengths, nearest_arc, point_at

__all__ = ["HALLWAY_STATE_FEATURES", "HALLWAY_SIGNS", "HallwayTask", "HallwayFeatures",
           "PathFollower", "PERSON_RETURNS", "in_sight", "near_people", "scan_points"]

HALLWAY_STATE_FEATURES = ("waypoint_heading", "path_progress", "wall_proximity",
                          "wall_proximity_0.5", "people_proximity", "people_room",
                          "people_predicted", "speed_squared", "turn_squared")
CONTROL_FEATURES = ("speed_effort", "turn_effort")
BLOCKING = 0.6
# What the features mean: progress and facing the waypoint are never worse; nearness to walls
# and people and effort never better.
HALLWAY_SIGNS = {"waypoint_heading": 1, "path_progress": 1, "wall_proximity": -1,
                 "wall_proximity_0.5": -1, "people_proximity": -1, "people_room": -1,
                 "people_predicted": -1, "speed_squared": -1, "turn_squared": -1,
                 "speed_effort": -1, "turn_effort": -1}


@dataclass
class HallwayTask:
    """One planning instant: waypoint (2,), the final destination (2,), scan points (M, 2) fixed
    in the map, people (P, 2) seen at time `now` moving at `velocities` (P, 2).

    For the planner's detour seeds and unstall rule it also reads as a one-obstacle task:
    `goal` is the waypoint and `obstacle_position(t)` the blocker - the nearest person or scan
    point within `BLOCKING` m of the straight way from `robot` (x, y) to the waypoint (the
    waypoint itself when nothing blocks: detours then pass beside it)."""

    waypoint: np.ndarray
    destination: np.ndarray
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    people: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    velocities: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    now: float = 0.0
    robot: Optional[np.ndarray] = None

    def __post_init__(self):
        self.waypoint = np.asarray(self.waypoint, float).reshape(2)
        self.destination = np.asarray(self.destination, float).reshape(2)
        self.points = np.asarray(self.points, float).reshape(-1, 2)
        self.people = np.asarray(self.people, float).reshape(-1, 2)
        self.velocities = np.asarray(self.velocities, float).reshape(-1, 2)
        if self.people.shape != self.velocities.shape:
            raise LfdError(f"{len(self.people)} people but {len(self.velocities)} velocities")
        self._blocker = self._find_blocker()

    @property
    def goal(self) -> np.ndarray:
        return self.waypoint

    def people_at(self, times) -> np.ndarray:
        """Predicted positions (T, P, 2) at times (T,)."""
        lead = np.asarray(times, float).reshape(-1, 1, 1) - self.now
        return self.people[None] + lead * self.velocities[None]

    def obstacle_position(self, t) -> np.ndarray:
        where, velocity = self._blocker
        lead = np.asarray(t, float)[..., None] - self.now
        return where + lead * velocity

    def _find_blocker(self):
        if self.robot is None:
            return self.waypoint, np.zeros(2)
        start = np.asarray(self.robot, float)[:2]
        span = self.waypoint - start
        length2 = max(float(span @ span), 1e-9)
        things = np.vstack([self.people, self.points])
        motion = np.vstack([self.velocities, np.zeros_like(self.points)])
        along = np.clip((things - start) @ span / length2, 0.0, 1.0)
        gap = np.hypot(*(start + along[:, None] * span - things).T)
        near = np.flatnonzero((gap < BLOCKING) & (along > 0.0))
        if not len(near):
            return self.waypoint, np.zeros(2)
        first = near[np.argmin(np.hypot(*(things[near] - start).T))]
        return things[first], motion[first]


# A scan return within PERSON_RETURNS m of a tracked person's centre is taken for that person
# (a person's radius, about 0.25 m, with slack for the tracker's error).
PERSON_RETURNS = 0.35


def near_people(points, people, radius: float) -> np.ndarray:
    """Which of `points` (N, 2) lie within `radius` m of one of `people` (P >= 1, 2): the scan
    returns that are a tracked person, not a wall."""
    people = np.asarray(people, float).reshape(-1, 2)
    return np.hypot(points[:, None, 0] - people[None, :, 0],
                    points[:, None, 1] - people[None, :, 1]).min(axis=1) < radius


def in_sight(pose, angles, ranges, *, margin: float = 0.3, people: Optional[np.ndarray] = None,
             person_radius: float = PERSON_RETURNS) -> Callable[[np.ndarray], bool]:
    """point -> True when the scan's nearest beam toward it reaches `margin` m past it. A beam
    that ends on a tracked person (within `person_radius` of one, as in `scan_points`) counts as
    open: a person hides the path behind them but is no wall, and a waypoint pulled in front of
    everyone in a crowd would have the robot creep (a waypoint it could pass within its
    look-ahead turns its progress feature around)."""
    x, y, yaw = (float(v) for v in pose[:3])
    angles, ranges = np.asarray(angles, float), np.asarray(ranges, float)
    if people is not None and len(people) and len(ranges):
        with np.errstate(invalid="ignore"):
            ends = np.column_stack([x + ranges * np.cos(yaw + angles),
                                    y + ranges * np.sin(yaw + angles)])
            on_person = near_people(ends, people, person_radius)
        ranges = np.where(np.isfinite(ranges) & on_person, np.inf, ranges)

    def visible(point) -> bool:
        if not len(angles):
            return True
        bearing = math.atan2(point[1] - y, point[0] - x) - yaw
        beam = int(np.argmin(np.abs(np.angle(np.exp(1j * (angles - bearing))))))
        return bool(ranges[beam] >= math.hypot(point[0] - x, point[1] - y) + margin
                    or not np.isfinite(ranges[beam]))
    return visible


def scan_points(pose, angles, ranges, *, sectors: int = 16, reach: float = 3.0,
                people: Optional[np.ndarray] = None,
                person_radius: float = PERSON_RETURNS) -> np.ndarray:
    """The nearest scan point of each of `sectors` equal sectors (within `reach` m), in the frame
    of `pose` (x, y, yaw of the laser); points within `person_radius` of a tracked person are
    left to the people features."""
    angles, ranges = np.asarray(angles, float), np.asarray(ranges, float)
    ok = np.isfinite(ranges) & (ranges < reach) & (ranges > 0.01)
    if not ok.any():
        return np.zeros((0, 2))
    x, y, yaw = (float(v) for v in pose[:3])
    world = yaw + angles[ok]
    xy = np.column_stack([x + ranges[ok] * np.cos(world), y + ranges[ok] * np.sin(world)])
    if people is not None and len(people):
        near = near_people(xy, people, person_radius)
        xy, world, kept = xy[~near], world[~near], ranges[ok][~near]
    else:
        kept = ranges[ok]
    sector = np.floor(np.mod(world - yaw + math.pi, 2 * math.pi) / (2 * math.pi) * sectors)
    points = []
    for s in np.unique(sector):
        members = np.flatnonzero(sector == s)
        points.append(xy[members[np.argmin(kept[members])]])
    return np.array(points).reshape(-1, 2)


class PathFollower:
    """Progress along a path (N, 2) and the local waypoint `lookahead` m ahead of it.

    The progress never goes back by more than `lookahead` (a path that loops past itself is
    followed in order) and is searched only `window` m ahead of the last one. Up to arc length
    `closely` (a detour the robot planned itself, kept clear of everything) the waypoint never
    skips a stretch out of sight: a door seen through a gap too narrow to drive would
    otherwise cut the detour's corner."""

    def __init__(self, path, *, lookahead: float = 1.5, window: float = 4.0,
                 closely: float = 0.0):
        self.path = np.asarray(path, float).reshape(-1, 2)
        if len(self.path) < 1:
            raise LfdError("a path needs at least one point")
        if not lookahead > 0:
            raise LfdError(f"the waypoint look-ahead must be positive, got {lookahead!r}")
        self.arc = arc_lengths(self.path)
        self.lookahead, self.window = float(lookahead), float(window)
        self.closely, self.progress = float(closely), 0.0

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    def point_at(self, s: float) -> np.ndarray:
        return point_at(self.path, s, self.arc)

    def update(self, position, visible: Optional[Callable[[np.ndarray], bool]] = None
               ) -> np.ndarray:
        """Move the progress to the path point nearest `position` (within the search window) and
        return the local waypoint: `lookahead` m further on, or with `visible` (point -> bool,
        e.g. from the scan) the furthest point up to there that is in sight (at least 0.5 m on:
        round a corner the waypoint waits at the corner)."""
        position = np.asarray(position, float)[:2]
        near = np.flatnonzero((self.arc >= self.progress - self.lookahead)
                              & (self.arc <= self.progress + self.window))
        if len(near):
            self.progress = max(self.progress - self.lookahead, self._nearest(position, near))
        ahead = self.lookahead
        if visible is not None and self.progress < self.closely:
            ahead = self._in_sight_throughout(visible)
        while visible is not None and ahead > 0.5 and not visible(self.point_at(self.progress + ahead)):
            ahead -= 0.25
        return self.point_at(self.progress + ahead)

    def _in_sight_throughout(self, visible) -> float:
        """How far on (at least 0.5 m, at most `lookahead`) the path up to arc `closely` stays
        in sight; past `closely` the plain rule takes over."""
        ahead = 0.5
        while ahead < self.lookahead and self.progress + ahead < self.closely:
            if not visible(self.point_at(self.progress + ahead + 0.25)):
                return ahead
            ahead += 0.25
        return self.lookahead

    def _nearest(self, position, near) -> float:
        """Arc length of the point nearest `position` on the segments starting at `near`."""
        first, last = int(near[0]), min(int(near[-1]) + 1, len(self.path) - 1)
        return float(self.arc[first] + nearest_arc(self.path[first:last + 1], position)[0])

    def distance_to_path(self, position) -> float:
        return float(np.hypot(*(self.point_at(self.progress) - np.asarray(position, float)[:2])))


class HallwayFeatures:
    """The hallway features (module docstring) with the one-obstacle FeatureSet's interface:
    `evaluate(states, actions, times, task, order)` -> FeatureValues and
    `weighted_first_order(...)` for planning."""

    kind = "hallway"

    def __init__(self, *, heading_softening: float = 0.3, predicted: float = 1.0):
        if not heading_softening > 0 or not predicted > 0:
            raise LfdError(f"heading_softening and predicted must be positive, got "
                           f"{heading_softening!r}, {predicted!r}")
        self.heading_softening, self.predicted = float(heading_softening), float(predicted)
        self.state_names = HALLWAY_STATE_FEATURES
        self.control_names = CONTROL_FEATURES
        self.names = self.state_names + self.control_names

    def get_params(self) -> Dict:
        return {"kind": self.kind, "heading_softening": self.heading_softening,
                "predicted": self.predicted}

    def _state_jets(self, states, times, task: HallwayTask, hessian: bool):
        count = len(states)
        px, py, yaw, v, w = Jet.variables(states, hessian)
        gx, gy = task.waypoint[0] - px, task.waypoint[1] - py
        heading = (gx * yaw.cos() + gy * yaw.sin()) / (gx.square() + gy.square()
                                                       + self.heading_softening ** 2).sqrt()
        jets = [heading, v * heading]
        jets += _gaussian_sums(states, task.points[None], (0.25, 0.5), hessian, count)
        people_now = task.people_at(times)
        jets += _gaussian_sums(states, people_now, (0.5, 1.0), hessian, count)
        ahead = task.people_at(np.asarray(times, float) + self.predicted)
        jets += _gaussian_sums(states, ahead, (0.5,), hessian, count, reach=self.predicted)
        jets += [v.square(), w.square()]
        return jets

    def evaluate(self, states, actions, times, task: HallwayTask, *, order: int = 2
                 ) -> FeatureValues:
        states, actions, times = as_trajectory(states, actions, times)
        jets = self._state_jets(states, times, task, hessian=order >= 2)
        count = len(states)
        control_jac = np.zeros((count, 2, 2))
        control_jac[:, 0, 0], control_jac[:, 1, 1] = 2.0 * actions[:, 0], 2.0 * actions[:, 1]
        control_hess = np.zeros((count, 2, 2, 2))
        control_hess[:, 0, 0, 0] = control_hess[:, 1, 1, 1] = 2.0
        return FeatureValues(np.stack([j.val for j in jets], axis=1),
                             np.stack([j.grad for j in jets], axis=1),
                             np.stack([j.hess for j in jets], axis=1) if order >= 2 else None,
                             actions ** 2, control_jac, control_hess)

    def weighted_first_order(self, states, actions, times, task, state_weights, control_weights):
        """(w . phi (T,), its state gradient (T, 5), its action gradient (T, 2)) for planning:
        the same values as `evaluate` (the reference; tested against it), written out by hand
        with the weights folded in and features of weight 0 skipped (a cycle's cost)."""
        states = np.atleast_2d(np.asarray(states, float))
        actions = np.atleast_2d(np.asarray(actions, float))
        count = len(states)
        times = np.broadcast_to(np.asarray(times, float), (count,))
        weight = dict(zip(self.state_names, np.asarray(state_weights, float)))
        px, py, yaw, v, w = states.T
        cos, sin = np.cos(yaw), np.sin(yaw)
        grad = np.zeros((count, 5))
        gx, gy = task.waypoint[0] - px, task.waypoint[1] - py
        root = np.sqrt(gx * gx + gy * gy + self.heading_softening ** 2)
        heading = (gx * cos + gy * sin) / root
        pull = weight["waypoint_heading"] + weight["path_progress"] * v
        value = pull * heading
        grad[:, 0] = pull * (heading * gx / root - cos) / root
        grad[:, 1] = pull * (heading * gy / root - sin) / root
        grad[:, 2] = pull * (gy * cos - gx * sin) / root
        grad[:, 3] = weight["path_progress"] * heading + 2.0 * weight["speed_squared"] * v
        grad[:, 4] = 2.0 * weight["turn_squared"] * w
        value = value + weight["speed_squared"] * v * v + weight["turn_squared"] * w * w
        frame = (px, py, cos, sin, v)
        groups = ((task.points[None], (("wall_proximity", 0.25), ("wall_proximity_0.5", 0.5)), 0.0),
                  (task.people_at(times), (("people_proximity", 0.5), ("people_room", 1.0)), 0.0),
                  (task.people_at(times + self.predicted), (("people_predicted", 0.5),),
                   self.predicted))
        for centres, widths, reach in groups:
            weighted = [(weight[name], width) for name, width in widths if weight[name] != 0.0]
            if weighted and centres.shape[1]:
                value = value + _weighted_gaussians(frame, centres, weighted, reach, grad)
        control_weights = np.asarray(control_weights, float)
        value = value + (actions ** 2) @ control_weights
        return value, grad, 2.0 * actions * control_weights


def _weighted_gaussians(frame, centres, weighted, reach: float, grad: np.ndarray) -> np.ndarray:
    """sum_k w_k sum_j exp(-|c_tj - p_t - reach v_t h_t|^2 / 2 s_k^2) over (w_k, s_k) in
    `weighted` and the centres (T or 1, J, 2); adds its state gradient to `grad` (T, 5)."""
    px, py, cos, sin, v = frame
    dx = centres[:, :, 0] - (px + reach * v * cos)[:, None]
    dy = centres[:, :, 1] - (py + reach * v * sin)[:, None]
    square = dx * dx + dy * dy
    value, slope = 0.0, 0.0
    for scale, width in weighted:
        each = scale * np.exp(square * (-0.5 / width ** 2))
        value = value + each
        slope = slope + each / width ** 2
    along_x, along_y = (slope * dx).sum(axis=1), (slope * dy).sum(axis=1)
    grad[:, 0] += along_x
    grad[:, 1] += along_y
    if reach:
        grad[:, 2] += reach * v * (along_y * cos - along_x * sin)
        grad[:, 3] += reach * (along_x * cos + along_y * sin)
    return value.sum(axis=1)


def _gaussian_sums(states, centres, widths, hessian: bool, count: int, reach: float = 0.0):
    """For each width, the Jet of sum_j exp(-|c_tj - p_t - reach v_t h_t|^2 / 2 width^2) over the
    centres (T or 1, J, 2) (reach 0: the robot's position itself)."""
    centres = np.broadcast_to(np.asarray(centres, float), (count,) + np.shape(centres)[1:])
    per = centres.shape[1]
    if per == 0:
        zero = Jet.variables(states[:, :1], hessian)[0] * 0.0
        grad = np.zeros((count, 5))
        hess = np.zeros((count, 5, 5)) if hessian else None
        return [Jet(zero.val, grad, hess) for _ in widths]
    px, py, yaw, v, _ = Jet.variables(np.repeat(states, per, axis=0), hessian)
    cx, cy = centres[:, :, 0].reshape(-1), centres[:, :, 1].reshape(-1)
    if reach:
        dx, dy = cx - px - v * yaw.cos() * reach, cy - py - v * yaw.sin() * reach
    else:
        dx, dy = cx - px, cy - py
    square = dx.square() + dy.square()
    sums = []
    for width in widths:
        each = (square * (-0.5 / width ** 2)).exp()
        hess = None if each.hess is None else each.hess.reshape(count, per, 5, 5).sum(axis=1)
        sums.append(Jet(each.val.reshape(count, per).sum(axis=1),
                        each.grad.reshape(count, per, 5).sum(axis=1), hess))
    return sums
