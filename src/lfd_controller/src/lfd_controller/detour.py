"""A detour round what holds the robot up, planned on the scan (no ROS).

A local controller that follows a fixed path can stand forever in front of what the path's
planner never saw: a cart beside a door frame, a group standing in a hall. move_base answers
that with its local costmap and a replanned global path; `plan_detour` is the same answer from
the floor map and the scan: in a square window round the robot the map's walls and the newest
scan's returns are obstacles (without a map, also what no scan of the last seconds has seen
free); A* on it (robot_common.gridplan, kept `clearance` m
from them and pushed toward the middle) joins the robot to the furthest point of the path, up
to `reach` m on, that the robot fits at; the path from there on is kept.
"""
import math
from typing import Optional, Sequence

import numpy as np

from robot_common.gridplan import CellCosts, NoPathError, cheapest_cells, clearance_map
from robot_common.maps import FREE, OCCUPIED, GridMap

__all__ = ["scan_window", "plan_detour"]


def scan_window(scans: Sequence, *, centre, half_width: float = 5.0, cell: float = 0.1,
                max_range: float = 8.0, grid: Optional[GridMap] = None) -> GridMap:
    """A GridMap of the square window of side 2 `half_width` m round `centre` (x, y) from
    `scans`, (laser (x, y, yaw), angles, ranges) oldest first. With the floor map `grid`: free
    where the map is free (what no beam has reached counts as free, as move_base's global
    planner counts it), but not where the newest scan has a return. Without a map, only what
    some scan has seen free is free (nearer than the return of either beam beside the cell's
    bearing; a beam without a return sees `max_range` m), and the newest returns are not."""
    x0, y0 = float(centre[0]) - half_width, float(centre[1]) - half_width
    size = int(math.ceil(2.0 * half_width / cell))
    window = GridMap(np.full((size, size), OCCUPIED, np.int8), cell, (x0, y0, 0.0))
    xs, ys = window.cell_to_world(*np.indices((size, size)))
    if grid is not None:
        window.cells[grid.is_free(xs, ys)] = FREE
    else:
        seen = np.zeros((size, size), bool)
        for laser, angles, ranges in scans:
            seen |= _seen_free(laser, np.asarray(angles, float), np.asarray(ranges, float), xs,
                               ys, max_range)
        window.cells[seen] = FREE
    if scans:
        (lx, ly, yaw), angles, ranges = scans[-1][0][:3], np.asarray(scans[-1][1], float), \
            np.asarray(scans[-1][2], float)
        hits = np.isfinite(ranges) & (ranges > 0.0) & (ranges <= max_range)
        rows, cols = window.world_to_cell(lx + ranges[hits] * np.cos(yaw + angles[hits]),
                                          ly + ranges[hits] * np.sin(yaw + angles[hits]))
        inside = window.inside(rows, cols)
        window.cells[rows[inside], cols[inside]] = OCCUPIED
    return window


def _seen_free(laser, angles, ranges, xs, ys, max_range: float) -> np.ndarray:
    """Where (xs, ys) lie nearer to `laser` than the return of either beam beside their bearing
    (an opening between two beams is seen open)."""
    if not len(angles):
        return np.zeros(np.shape(xs), bool)
    lx, ly, yaw = (float(v) for v in laser[:3])
    reach = np.where(np.isfinite(ranges) & (ranges > 0.0), np.minimum(ranges, max_range),
                     max_range)
    order = np.argsort(np.mod(angles, 2.0 * math.pi))
    bearings, reach = np.mod(angles[order], 2.0 * math.pi), reach[order]
    bearing = np.mod(np.arctan2(ys - ly, xs - lx) - yaw, 2.0 * math.pi)
    after = np.searchsorted(bearings, bearing) % len(bearings)
    return np.hypot(xs - lx, ys - ly) < np.maximum(reach[after], reach[after - 1])


def plan_detour(path_follower, position, scans: Sequence, *, clearance: float,
                reach: float = 5.0, half_width: float = 5.0, cell: float = 0.1,
                comfort: float = 0.6, wall_cost: float = 2.0,
                grid: Optional[GridMap] = None) -> Optional[np.ndarray]:
    """A new path (N, 2) from `position` to the furthest point of the followed path (a
    hallway_features.PathFollower; from its progress up to `reach` m on, at least 1 m on) that it
    can join through the free cells of scan_window(`scans`, `grid`) kept `clearance` m from the
    others, then the path on from there; None when there is no such point. The robot's own spot
    counts as free: it may stand closer than `clearance` to what holds it up."""
    position = np.asarray(position, float)[:2]
    grid = scan_window(scans, centre=position, half_width=half_width, cell=cell, grid=grid)
    room = clearance_map(grid, max(comfort, clearance))
    cost = np.where(room >= clearance, 1.0 + wall_cost * np.clip(
        (comfort - room) / comfort, 0.0, 1.0), np.inf)
    rows, cols = np.indices(cost.shape)
    xs, ys = grid.cell_to_world(rows, cols)
    around = np.hypot(xs - position[0], ys - position[1]) <= clearance
    cost[around & (grid.cells == FREE)] = 1.0 + wall_cost
    start = grid.world_to_cell(*position)
    if not (grid.inside(*start) and np.isfinite(cost[start])):
        return None
    for along in np.arange(min(reach, path_follower.length - path_follower.progress), 0.99, -0.25):
        target = path_follower.point_at(path_follower.progress + along)
        goal = grid.world_to_cell(*target)
        if not (grid.inside(*goal) and np.isfinite(cost[goal])):
            continue
        try:
            cells, _ = cheapest_cells(CellCosts(cost[None]), tuple(map(int, start)),
                                      tuple(map(int, goal)))
        except NoPathError:
            continue
        rows_, cols_ = np.array([c[0] for c in cells]), np.array([c[1] for c in cells])
        points = np.column_stack(grid.cell_to_world(rows_, cols_))
        points[0], points[-1] = position, target
        rest = path_follower.path[path_follower.arc > path_follower.progress + along + 1e-6]
        return np.vstack([_thinned(points), rest])
    return None


def _thinned(points: np.ndarray, step: int = 3) -> np.ndarray:
    """Every `step`-th point of a cell path (the ends kept): the staircase of cell centres is
    no path a robot drives."""
    keep = list(range(0, len(points) - 1, step)) + [len(points) - 1]
    return points[keep]

