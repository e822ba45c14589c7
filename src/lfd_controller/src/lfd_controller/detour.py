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
from typing import NamedTuple, Optional, Sequence

import numpy as np
from scipy.ndimage import label

from robot_common.gridplan import CellCosts, NoPathError, cheapest_cells, clearance_map, path_length
from robot_common.maps import FREE, OCCUPIED, GridMap

__all__ = ["Detour", "scan_window", "plan_detour", "plan_give_way"]


class Detour(NamedTuple):
    """A detour's whole new path (N, 2) and the arc length (m) at which it rejoins the old one."""

    path: np.ndarray
    rejoins: float


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
                grid: Optional[GridMap] = None) -> Optional[Detour]:
    """A Detour: a new path from `position` to the furthest point of the followed path (a
    hallway_features.PathFollower; from its progress up to `reach` m on, at least 1 m on) that it
    can join through the free cells of scan_window(`scans`, `grid`) kept `clearance` m from the
    others, then the path on from there; None when there is no such point. The robot's own spot
    counts as free: it may stand closer than `clearance` to what holds it up."""
    position = np.asarray(position, float)[:2]
    grid = scan_window(scans, centre=position, half_width=half_width, cell=cell, grid=grid)
    cost = _step_costs(grid, position, clearance, comfort, wall_cost)
    joined = _joined(grid, cost, position)
    for along in np.arange(min(reach, path_follower.length - path_follower.progress), 0.99, -0.25):
        target = path_follower.point_at(path_follower.progress + along)
        if not joined(target):
            continue
        points = _cell_path(grid, cost, position, target)
        if points is not None:
            rest = path_follower.path[path_follower.arc > path_follower.progress + along + 1e-6]
            return Detour(np.vstack([points, rest]), path_length(points))
    return None


def plan_give_way(path_follower, position, people, scans, *, clearance: float,
                  ways=None, reach: float = 2.5, aside: float = 0.8, clear: float = 1.0,
                  comfort: float = 0.6, wall_cost: float = 2.0, tries: int = 5,
                  grid: Optional[GridMap] = None) -> Optional[np.ndarray]:
    """A path (N, 2) from `position` to the nearest spot, within `reach` m, out of the way of
    `people` (P, 2) who wait for the robot: on the robot's far side from them (it makes way by
    moving away, not past them), `aside` m from the path's stretch round the robot (3 m back,
    4 m on: they come along it), `clear` m from each of them and from where each will walk on
    (straight lines: toward the robot and on past it - who waits for a robot has it in their
    way - and the way they were walking, `ways`: unit vectors (P, 2), NaN unknown), kept
    `clearance` m from what scan_window(`scans`, `grid`) shows; None when no such spot can be
    reached (the `tries` nearest are tried; the way there is dearer near them, and one longer
    than `reach` + 1 m, or coming closer to them than the robot is, does not count)."""
    position = np.asarray(position, float)[:2]
    grid = scan_window(scans, centre=position, half_width=reach + 1.0, grid=grid)
    cost = _step_costs(grid, position, clearance, comfort, wall_cost)
    xs, ys = grid.cell_to_world(*np.indices(cost.shape))
    people = np.asarray(people, float).reshape(-1, 2)
    towards = people.mean(axis=0) - position if len(people) else np.zeros(2)
    spots = np.isfinite(cost) & (np.hypot(xs - position[0], ys - position[1]) <= reach) & (
        (xs - position[0]) * towards[0] + (ys - position[1]) * towards[1] <= 0.0)
    stretch = [path_follower.point_at(s) for s in np.arange(
        path_follower.progress - 3.0, path_follower.progress + 4.0, 0.1)]
    walks = [person + along * way for person, way in _walking_lines(people, position, ways)
             for along in np.arange(0.0, np.hypot(*(person - position)) + reach + 1.0, 0.1)]
    for points, room in ((stretch, aside), (people, clear), (walks, clear)):
        for x, y in points:
            spots &= np.hypot(xs - x, ys - y) >= room
    if len(people):     # the way there keeps off them: dearer the nearer it comes
        apart = np.min([np.hypot(xs - x, ys - y) for x, y in people], axis=0)
        cost = cost + 2.0 * wall_cost * np.clip((clear - apart) / clear, 0.0, 1.0)
    now = _nearest(position[None], people) if len(people) else math.inf
    order = np.argsort(np.hypot(xs[spots] - position[0], ys[spots] - position[1]))
    joined = _joined(grid, cost, position)
    for index in order[:tries]:
        spot = (xs[spots][index], ys[spots][index])
        points = _cell_path(grid, cost, position, spot) if joined(spot) else None
        if points is not None and path_length(points) <= reach + 1.0 and not (
                len(people) and _nearest(points, people) < now - grid.resolution):
            return points
    return None


def _walking_lines(people: np.ndarray, position: np.ndarray, ways=None):
    """(person, unit vector) pairs: each person toward `position`, and along `ways` (P, 2)
    where it is known (not NaN)."""
    pairs = []
    for index, person in enumerate(people):
        toward = position - person
        pairs.append((person, toward / max(float(np.hypot(*toward)), 1e-9)))
        if ways is not None and np.all(np.isfinite(ways[index])):
            pairs.append((person, np.asarray(ways[index], float)))
    return pairs


def _nearest(points: np.ndarray, people: np.ndarray) -> float:
    """The closest any of `points` (N, 2) and the straight lines between them come to `people`
    (P, 2)."""
    dense = np.vstack([np.linspace(a, b, 5) for a, b in zip(points[:-1], points[1:])]) \
        if len(points) > 1 else points
    return float(np.hypot(*(dense[:, None, :] - people[None, :, :]).transpose(2, 0, 1)).min())


def _step_costs(grid: GridMap, position, clearance: float, comfort: float,
                wall_cost: float) -> np.ndarray:
    """Each cell's cost to step on: infinite nearer than `clearance` to an obstacle, dearer
    within `comfort` of one; the robot's own spot (within `clearance` of `position`) free."""
    room = clearance_map(grid, max(comfort, clearance))
    cost = np.where(room >= clearance, 1.0 + wall_cost * np.clip(
        (comfort - room) / comfort, 0.0, 1.0), np.inf)
    xs, ys = grid.cell_to_world(*np.indices(cost.shape))
    around = np.hypot(xs - position[0], ys - position[1]) <= clearance
    cost[around & (grid.cells == FREE)] = 1.0 + wall_cost
    return cost


def _joined(grid: GridMap, cost: np.ndarray, start_point):
    """point -> whether a path on `cost` can join it to `start_point`: both in the same
    8-connected piece of the passable cells (what _cell_path's search moves through). One labelling
    instead of a search that fails for every target out of reach: each such search visits every
    cell the robot can reach, and a detour tries up to 17 targets."""
    pieces, _ = label(np.isfinite(cost), structure=np.ones((3, 3), int))
    start = grid.world_to_cell(*start_point)
    mine = pieces[start] if grid.inside(*start) else 0

    def joined(point) -> bool:
        cell = grid.world_to_cell(*point)
        return bool(mine) and bool(grid.inside(*cell)) and pieces[cell] == mine
    return joined


def _cell_path(grid: GridMap, cost: np.ndarray, start_point, end_point) -> Optional[np.ndarray]:
    """The cheapest path (thinned, its ends the two points) between two points on `cost`, or
    None when either end is off the free cells or nothing joins them."""
    start, goal = grid.world_to_cell(*start_point), grid.world_to_cell(*end_point)
    if not all(grid.inside(*cell) and np.isfinite(cost[cell]) for cell in (start, goal)):
        return None
    try:
        cells, _ = cheapest_cells(CellCosts(cost[None]), tuple(map(int, start)),
                                  tuple(map(int, goal)))
    except NoPathError:
        return None
    rows, cols = np.array([c[0] for c in cells]), np.array([c[1] for c in cells])
    points = np.column_stack(grid.cell_to_world(rows, cols))
    points[0], points[-1] = start_point, end_point
    return _thinned(points)


def _thinned(points: np.ndarray, step: int = 3) -> np.ndarray:
    """Every `step`-th point of a cell path (the ends kept): the staircase of cell centres is
    no path a robot drives."""
    keep = list(range(0, len(points) - 1, step)) + [len(points) - 1]
    return points[keep]

