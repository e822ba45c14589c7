"""One errand's bookkeeping, without ROS: arrival, progress, blockage, when to re-plan, and what
the map looks like with what the laser saw in the way.

`Errand` is fed the robot's position and the clock; it answers what the action server does next
(`Errand.check`): go on, arrive, re-plan because the robot is held up, or re-plan because the
crowd forecast is due again. `with_obstacles` marks laser points on a copy of the map, so the
re-plan goes round what blocked the path (move_base's obstacle layer does the same)."""
import math
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from robot_common.maps import FREE, OCCUPIED, GridMap
from robot_common.polylines import arc_lengths, nearest_arc

__all__ = ["Errand", "ErrandRules", "Verdict", "with_obstacles", "remaining_path",
           "nearest_clear", "at_hour_of_week"]

WEEK = 7 * 86400.0
# Laser points kept as in the way: one per square this size (m); a robot held up for seconds
# sees the same thing many times over. Of what it saw while held, only what stood still: a
# STILL_CELL m square seen in STILL_SIGHTINGS looks or more (someone walking past crosses one
# in a look or two at the server's 5 per second).
SIGHTING_CELL, STILL_CELL, STILL_SIGHTINGS = 0.05, 0.25, 3


def at_hour_of_week(now: float, hour: float) -> float:
    """The time (s since the epoch) at `hour` hours after Monday 00:00 UTC of the week holding
    `now` (the epoch, 1970-01-01, was a Thursday)."""
    monday = math.floor((now + 3 * 86400.0) / WEEK) * WEEK - 3 * 86400.0
    return monday + hour * 3600.0


@dataclass
class ErrandRules:
    """When an errand is done, held up or due for a new plan (defaults written once, here)."""

    goal_tolerance: float = 0.3   # m from the goal counts as arrived
    progress_step: float = 0.3    # m closer to the goal (along the path) counts as progress
    blocked_after: float = 15.0   # s without progress: the path counts as blocked
    replan_period: float = 30.0   # s between looks at a newer crowd forecast
    max_replans: int = 5          # blocked re-plans per goal before it is aborted


@dataclass
class Verdict:
    """What to do now: "go", "arrived", "blocked" (re-plan round it) or "forecast" (a newer
    crowd forecast may give a better path); `reason` says why in words."""

    action: str
    reason: str = ""


@dataclass
class Errand:
    """A goal being driven to along a planned path."""

    goal: Sequence[float]
    rules: ErrandRules
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    best_remaining: float = math.inf
    last_progress: float = 0.0
    last_plan: float = 0.0
    replans: int = 0
    # what the laser showed in the way when the path was blocked (map frame), kept for the
    # errand so that a re-plan never returns to a way already found blocked - until a newer
    # scan sees past it (seen_clear)
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # what it showed since the robot last got on: held up, a controller trying its own
    # recoveries may have turned its back on what holds it when the path counts as blocked
    held_sightings: List[np.ndarray] = field(default_factory=list)

    def sighted(self, points: np.ndarray) -> None:
        """Laser points the map lacks, seen now; those since the last progress count as in the
        way when the path is blocked."""
        self.held_sightings.append(np.asarray(points, float).reshape(-1, 2))

    def saw_blocking(self, points: np.ndarray) -> np.ndarray:
        """Add laser points seen in the way now, and those that stood still since the last
        progress (_standing_still), one per SIGHTING_CELL m square; all of them so far."""
        seen = np.vstack([self.obstacles, np.asarray(points, float).reshape(-1, 2),
                          _standing_still(self.held_sightings)])
        self.held_sightings = []
        cells = np.unique(np.round(seen / SIGHTING_CELL).astype(np.int64), axis=0,
                          return_index=True)[1]
        self.obstacles = seen[np.sort(cells)]
        return self.obstacles

    def seen_clear(self, sees_past: Callable[[np.ndarray], np.ndarray]) -> int:
        """Forget the kept obstacles that a newer scan sees past (`sees_past`: points (N, 2) ->
        mask, robot_common.maps.seen_through): people who stood in a way and left no longer
        close it for the rest of the errand. How many were forgotten."""
        if not len(self.obstacles):
            return 0
        clear = np.asarray(sees_past(self.obstacles), bool)
        self.obstacles = self.obstacles[~clear]
        return int(clear.sum())

    def follow(self, path: np.ndarray, now: float) -> None:
        """A new path to follow from now on (progress is measured along it)."""
        self.path = np.asarray(path, float)
        self.best_remaining, self.last_progress, self.last_plan = math.inf, now, now
        self.held_sightings = []

    def distance_to_goal(self, xy: Sequence[float]) -> float:
        return math.hypot(xy[0] - self.goal[0], xy[1] - self.goal[1])

    def remaining(self, xy: Sequence[float]) -> float:
        """Length (m) of the path left from the point of the path nearest `xy`."""
        if len(self.path) < 2:
            return self.distance_to_goal(xy)
        return float(arc_lengths(self.path)[-1] - nearest_arc(self.path, xy)[0])

    def check(self, xy: Sequence[float], now: float) -> Verdict:
        """The verdict for the robot at `xy` at time `now` (s)."""
        if self.distance_to_goal(xy) <= self.rules.goal_tolerance:
            return Verdict("arrived", f"within {self.rules.goal_tolerance:g} m of the goal")
        left = self.remaining(xy)
        if left < self.best_remaining - self.rules.progress_step:
            self.best_remaining, self.last_progress = left, now
            self.held_sightings = []
        held = now - self.last_progress
        if held > self.rules.blocked_after:
            return Verdict("blocked", f"no progress for {held:.0f} s, {left:.1f} m from the goal")
        if now - self.last_plan >= self.rules.replan_period:
            return Verdict("forecast", f"{self.rules.replan_period:g} s since the last plan")
        return Verdict("go")


def _standing_still(sightings: List[np.ndarray]) -> np.ndarray:
    """The points of `sightings` (each (N, 2)) in STILL_CELL m squares that STILL_SIGHTINGS or
    more of them saw."""
    if not sightings:
        return np.zeros((0, 2))
    points = np.vstack(sightings)
    cells = np.floor(points / STILL_CELL).astype(np.int64)
    looks = np.repeat(np.arange(len(sightings)), [len(s) for s in sightings])
    pairs = np.unique(np.column_stack([cells, looks]), axis=0)        # a square once per look
    squares, counts = np.unique(pairs[:, :2], axis=0, return_counts=True)
    still = {tuple(square) for square in squares[counts >= STILL_SIGHTINGS]}
    return points[[tuple(cell) in still for cell in cells]].reshape(-1, 2)


def remaining_path(path: np.ndarray, xy: Sequence[float]) -> np.ndarray:
    """The part of `path` (N, 2) still ahead of the robot at `xy`, starting at `xy`: the
    vertices beyond the point of the path nearest the robot (a corner just ahead is kept: the
    way from the robot straight to the vertex after it would cut the corner)."""
    path = np.asarray(path, float).reshape(-1, 2)
    here = np.asarray(xy, float)[None, :2]
    if len(path) < 2:
        return np.vstack([here, path])
    ahead = path[arc_lengths(path) > nearest_arc(path, here[0])[0] + 1e-9]
    return np.vstack([here, ahead if len(ahead) else path[-1:]])


def nearest_clear(search, point: Sequence[float], reach: float) -> Tuple[float, float]:
    """`point` itself when the robot fits there on `search` (a robot_common.gridplan.SearchGrid),
    else the centre of the nearest search cell where it fits within `reach` m (a robot that
    stopped close to what blocked it plans from the nearest clear spot, as a goal a little
    too close to a wall is taken at the nearest clear one); `point` when there is none."""
    coarse = search.coarse
    row, col = coarse.world_to_cell(point[0], point[1])
    if coarse.inside(row, col) and search.passable[row, col]:
        return float(point[0]), float(point[1])
    cells = int(math.ceil(reach / coarse.resolution))
    rows, cols = np.mgrid[max(0, row - cells):min(coarse.height, row + cells + 1),
                          max(0, col - cells):min(coarse.width, col + cells + 1)]
    if rows.size == 0:
        return float(point[0]), float(point[1])
    xs, ys = coarse.cell_to_world(rows, cols)
    gap = np.hypot(xs - point[0], ys - point[1])
    gap[~search.passable[rows, cols] | (gap > reach)] = np.inf
    best = np.unravel_index(int(np.argmin(gap)), gap.shape)
    if not np.isfinite(gap[best]):
        return float(point[0]), float(point[1])
    return float(xs[best]), float(ys[best])


def with_obstacles(grid: GridMap, points: np.ndarray, radius: float,
                   keep_clear: Optional[Sequence[float]] = None, keep_radius: float = 0.0) -> GridMap:
    """A copy of `grid` with discs of `radius` (m) around `points` (N, 2) marked occupied,
    except within `keep_radius` of `keep_clear` (the robot itself must stay free to plan from)."""
    cells = grid.cells.copy()
    points = np.asarray(points, float).reshape(-1, 2)
    if len(points):
        reach = int(math.ceil(radius / grid.resolution))
        offsets = np.arange(-reach, reach + 1)
        d_row, d_col = np.meshgrid(offsets, offsets, indexing="ij")
        inside = np.hypot(d_row, d_col) * grid.resolution <= radius + 1e-9
        d_row, d_col = d_row[inside], d_col[inside]
        rows, cols = grid.world_to_cell(points[:, 0], points[:, 1])
        rows = (np.asarray(rows)[:, None] + d_row[None]).ravel()
        cols = (np.asarray(cols)[:, None] + d_col[None]).ravel()
        ok = np.asarray(grid.inside(rows, cols), bool)
        cells[rows[ok], cols[ok]] = OCCUPIED
    if keep_clear is not None and keep_radius > 0:
        row, col = grid.world_to_cell(keep_clear[0], keep_clear[1])
        reach = int(math.ceil(keep_radius / grid.resolution)) + 1
        rows, cols = np.mgrid[max(0, row - reach):min(grid.height, row + reach + 1),
                              max(0, col - reach):min(grid.width, col + reach + 1)]
        xs, ys = grid.cell_to_world(rows, cols)
        near = (np.hypot(xs - keep_clear[0], ys - keep_clear[1]) <= keep_radius) \
            & (grid.cells[rows, cols] == FREE)
        cells[rows[near], cols[near]] = FREE
    return GridMap(cells, grid.resolution, grid.origin, dict(grid.meta))
