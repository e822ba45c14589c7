"""Shortest collision-free paths on an occupancy grid (A*, 8-connected), without ROS.

What a global planner (move_base's) gives a local controller: a polyline from start to goal
through free space, kept `clearance` metres from anything that is not free and pushed toward the
middle of halls (each cell closer than `comfort` metres to a wall costs up to `wall_cost` times
its length more). The map is searched at `cell_size` metres per cell (the map downsampled: a
coarse cell is free only where all its fine cells are).
"""
import heapq
import math
from typing import Sequence, Tuple

import numpy as np

from robot_common.errors import MapError
from robot_common.maps import FREE, GridMap

__all__ = ["clearance_map", "plan_path", "path_length", "NoPathError"]

_MOVES = [(d_row, d_col) for d_row in (-1, 0, 1) for d_col in (-1, 0, 1) if d_row or d_col]


class NoPathError(MapError):
    """No free path joins the start and the goal (or one of them is not in free space)."""


def clearance_map(grid: GridMap, limit: float) -> np.ndarray:
    """Distance (m, 8-connected chamfer, capped at `limit`) from each cell to the nearest cell
    that is not free (cells outside the map count as not free)."""
    free = grid.cells == FREE
    steps = int(math.ceil(limit / grid.resolution))
    distance = np.where(free, np.inf, 0.0)
    padded_rows, padded_cols = free.shape[0] + 2, free.shape[1] + 2
    for _ in range(steps):
        padded = np.zeros((padded_rows, padded_cols))
        padded[1:-1, 1:-1] = distance
        best = distance.copy()
        for d_row, d_col in _MOVES:
            shifted = padded[1 + d_row:padded_rows - 1 + d_row, 1 + d_col:padded_cols - 1 + d_col]
            best = np.minimum(best, shifted + grid.resolution * math.hypot(d_row, d_col))
        if np.array_equal(best, distance):
            break
        distance = best
    return np.minimum(distance, limit)


def plan_path(grid: GridMap, start: Sequence[float], goal: Sequence[float], *,
              clearance: float = 0.3, comfort: float = 1.0, wall_cost: float = 2.0,
              cell_size: float = 0.1) -> np.ndarray:
    """Waypoints (N, 2) in metres from `start` to `goal` (both included, as given).

    NoPathError when start or goal is closer than `clearance` to a wall or no path joins them."""
    factor = max(1, int(round(cell_size / grid.resolution)))
    coarse = grid.downsample(factor)
    distance = clearance_map(coarse, max(comfort, clearance))
    passable = distance >= clearance
    extra = wall_cost * np.clip((comfort - distance) / max(comfort, 1e-9), 0.0, 1.0)
    ends = []
    for name, (x, y) in (("start", start), ("goal", goal)):
        row, col = coarse.world_to_cell(x, y)
        if not (coarse.inside(row, col) and passable[row, col]):
            raise NoPathError(f"the {name} ({x:.2f}, {y:.2f}) is not {clearance} m clear of walls")
        ends.append((int(row), int(col)))
    cells = _astar(passable, 1.0 + extra, ends[0], ends[1])
    xs, ys = coarse.cell_to_world(np.array([c[0] for c in cells]), np.array([c[1] for c in cells]))
    points = np.column_stack([xs, ys])
    points[0], points[-1] = start, goal
    return points


def _astar(passable: np.ndarray, cost: np.ndarray, start: Tuple[int, int],
           goal: Tuple[int, int]):
    rows, cols = passable.shape
    best = {start: 0.0}
    parent = {start: None}
    frontier = [(0.0, 0.0, start)]
    while frontier:
        _, so_far, cell = heapq.heappop(frontier)
        if cell == goal:
            break
        if so_far > best.get(cell, math.inf):
            continue
        for d_row, d_col in _MOVES:
            row, col = cell[0] + d_row, cell[1] + d_col
            if not (0 <= row < rows and 0 <= col < cols and passable[row, col]):
                continue
            step = math.hypot(d_row, d_col) * 0.5 * (cost[cell] + cost[row, col])
            total = so_far + step
            if total < best.get((row, col), math.inf):
                best[(row, col)], parent[(row, col)] = total, cell
                guess = total + math.hypot(goal[0] - row, goal[1] - col)
                heapq.heappush(frontier, (guess, total, (row, col)))
    if goal not in parent:
        raise NoPathError(f"no free path from cell {start} to cell {goal}")
    cells, cell = [], goal
    while cell is not None:
        cells.append(cell)
        cell = parent[cell]
    return cells[::-1]


def path_length(points: np.ndarray) -> float:
    """Length (m) of a polyline (N, 2)."""
    points = np.asarray(points, float)
    return float(np.hypot(*np.diff(points, axis=0).T).sum()) if len(points) > 1 else 0.0
