"""Shortest collision-free paths on an occupancy grid (A*, 8-connected), without ROS.

What a global planner (move_base's) gives a local controller: a polyline from start to goal
through free space, kept `clearance` metres from anything that is not free and pushed toward the
middle of halls (each cell closer than `comfort` metres to a wall costs up to `wall_cost` times
its length more). The map is searched at `cell_size` metres per cell (the map downsampled: a
coarse cell is free only where all its fine cells are).

One search serves every planner: `cheapest_cells` runs A* over `CellCosts`, per-cell costs per
unit of length that may change with a clock (a time of day) carried along the search: each cell
also has a pace (clock per unit of length), the costs are linear in the clock between stamps and
held beyond the ends, and a move is costed at the clock when it starts. `plan_path` is the case
of one stamp and no clock.
"""
import bisect
import heapq
import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from robot_common.errors import MapError
from robot_common.maps import FREE, GridMap
from robot_common.polylines import path_length

__all__ = ["clearance_map", "plan_path", "path_length", "NoPathError", "SearchGrid",
           "CellCosts", "cheapest_cells"]

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


class SearchGrid:
    """A map prepared for searching at `cell_size`: the coarse map, each coarse cell's clearance
    (m), where the robot fits (`passable`) and the wall penalty (`extra`, 0 .. `wall_cost`).

    Clearances between coarse cells (as `plan_path` measures them) overstate the room by up to
    half a coarse cell (a wall cell's centre is farther than its edge); with `fine_clearance`
    each coarse cell's clearance is read at its centre from the map at about 0.1 m instead."""

    def __init__(self, grid: GridMap, *, clearance: float = 0.3, comfort: float = 1.0,
                 wall_cost: float = 2.0, cell_size: float = 0.1, fine_clearance: bool = False):
        factor = max(1, int(round(cell_size / grid.resolution)))
        self.coarse = grid.downsample(factor)
        self.clearance = clearance
        limit = max(comfort, clearance)
        if fine_clearance:
            fine = grid.downsample(max(1, int(round(min(cell_size, 0.1) / grid.resolution))))
            rows, cols = np.indices(self.coarse.cells.shape)
            fine_rows, fine_cols = fine.world_to_cell(*self.coarse.cell_to_world(rows, cols))
            self.distance = clearance_map(fine, limit)[np.minimum(fine_rows, fine.height - 1),
                                                       np.minimum(fine_cols, fine.width - 1)]
        else:
            self.distance = clearance_map(self.coarse, limit)
        self.passable = self.distance >= clearance
        self.extra = wall_cost * np.clip((comfort - self.distance) / max(comfort, 1e-9), 0.0, 1.0)

    @property
    def cell_size(self) -> float:
        return self.coarse.resolution

    def end_cell(self, name: str, point: Sequence[float]) -> Tuple[int, int]:
        """(row, col) of a start or goal; NoPathError when the robot does not fit there."""
        x, y = float(point[0]), float(point[1])
        row, col = self.coarse.world_to_cell(x, y)
        if not (self.coarse.inside(row, col) and self.passable[row, col]):
            raise NoPathError(f"the {name} ({x:.2f}, {y:.2f}) is not {self.clearance} m clear "
                              f"of walls")
        return int(row), int(col)

    def polyline(self, cells: Sequence[Tuple[int, int]], start, goal) -> np.ndarray:
        """Cell centres (N, 2) of `cells`, the first and last replaced by `start` and `goal`
        (two points when both lie in one cell)."""
        cells = list(cells) * 2 if len(cells) == 1 else cells
        rows, cols = np.array([c[0] for c in cells]), np.array([c[1] for c in cells])
        points = np.column_stack(self.coarse.cell_to_world(rows, cols))
        points[0], points[-1] = start[:2], goal[:2]
        return points


def plan_path(grid: GridMap, start: Sequence[float], goal: Sequence[float], *,
              clearance: float = 0.3, comfort: float = 1.0, wall_cost: float = 2.0,
              cell_size: float = 0.1) -> np.ndarray:
    """Waypoints (N, 2) in metres from `start` to `goal` (both included, as given).

    NoPathError when start or goal is closer than `clearance` to a wall or no path joins them."""
    search = SearchGrid(grid, clearance=clearance, comfort=comfort, wall_cost=wall_cost,
                        cell_size=cell_size)
    ends = [search.end_cell("start", start), search.end_cell("goal", goal)]
    cost = np.where(search.passable, 1.0 + search.extra, np.inf)
    cells, _ = cheapest_cells(CellCosts(cost[None]), ends[0], ends[1])
    return search.polyline(cells, start, goal)


@dataclass
class CellCosts:
    """Cost per unit of length (cell side) of each cell, at clock `stamps` (T,): `cost` (T, rows,
    cols), inf where the robot may not go; `pace` (T, rows, cols) the clock's advance per unit of
    length (None: the clock stands). Linear in the clock between stamps, held beyond the ends."""

    cost: np.ndarray
    pace: Optional[np.ndarray] = None
    stamps: Sequence[float] = (0.0,)

    def __post_init__(self):
        self.cost = np.asarray(self.cost, float)
        if self.cost.ndim != 3 or len(self.stamps) != self.cost.shape[0]:
            raise MapError(f"cell costs must be (stamps, rows, cols) with one stamp per layer, "
                           f"got {self.cost.shape} for {len(self.stamps)} stamps")
        if np.any(np.diff(self.stamps) <= 0):
            raise MapError("cell cost stamps must increase")
        finite = self.cost[np.isfinite(self.cost)]
        if finite.size and finite.min() <= 0:
            raise MapError(f"cell costs must be positive, got {finite.min()}")

    def floor(self) -> float:
        """The smallest finite cost per unit of length (for the A* bound)."""
        finite = self.cost[np.isfinite(self.cost)]
        return float(finite.min()) if finite.size else 1.0


def cheapest_cells(costs: CellCosts, start: Tuple[int, int], goal: Tuple[int, int],
                   clock: float = 0.0) -> Tuple[List[Tuple[int, int]], List[float]]:
    """A* from cell `start` to cell `goal` (8-connected; a move of length 1 or sqrt 2 costs its
    length x the mean cost of its two cells at the clock when it starts). Returns the cells and
    the clock on reaching each; NoPathError when none joins them.

    With a clock, the search keeps one label per cell (the cheapest): exact when the cost is the
    clock itself and departing later never arrives sooner (FIFO: each cell's pace x its length
    changes slower than the clock between stamps)."""
    rows, cols = costs.cost.shape[1:]
    width = cols + 2                                   # a border of impassable cells
    layers = _flat_layers(costs, rows, cols)
    stamps = list(costs.stamps)
    moves = [(d_row * width + d_col, math.hypot(d_row, d_col)) for d_row, d_col in _MOVES]
    first, last = (start[0] + 1) * width + start[1] + 1, (goal[0] + 1) * width + goal[1] + 1
    guess = _octile_to(goal, rows, cols, costs.floor()).tolist()
    best = [math.inf] * ((rows + 2) * width)
    parent, when = {first: -1}, {first: float(clock)}
    best[first] = 0.0
    frontier = [(0.0, 0.0, first)]
    low = high = math.inf
    while frontier:
        _, so_far, here = heapq.heappop(frontier)
        if here == last:
            break
        if so_far > best[here]:
            continue
        now = when[here]
        if not low <= now < high:                      # another stamp's layer
            cost, slope, pace, pace_slope, low, high, base = _layer_at(layers, stamps, now)
        share = max(now - base, 0.0)                   # clock past the layer's stamp
        cost_here = cost[here] + share * slope[here]
        pace_here = pace[here] + share * pace_slope[here]
        for offset, length in moves:
            there = here + offset
            total = so_far + length * 0.5 * (cost_here + cost[there] + share * slope[there])
            if total < best[there]:
                best[there], parent[there] = total, here
                when[there] = now + length * 0.5 * (pace_here + pace[there]
                                                    + share * pace_slope[there])
                heapq.heappush(frontier, (total + guess[there], total, there))
    if last not in parent:
        raise NoPathError(f"no free path from cell {start} to cell {goal}")
    cells, clocks, cell = [], [], last
    while cell != -1:
        cells.append((cell // width - 1, cell % width - 1))
        clocks.append(when[cell])
        cell = parent[cell]
    return cells[::-1], clocks[::-1]


def _flat_layers(costs: CellCosts, rows: int, cols: int) -> list:
    """Per stamp: (cost, cost slope per clock unit, pace, pace slope) as flat lists over the
    grid with a one-cell impassable border (slopes toward the next stamp; 0 for the last)."""
    cost = np.pad(costs.cost, ((0, 0), (1, 1), (1, 1)), constant_values=np.inf)
    pace = np.zeros_like(cost) if costs.pace is None else \
        np.pad(np.asarray(costs.pace, float), ((0, 0), (1, 1), (1, 1)))
    layers = []
    for k in range(len(costs.stamps)):
        if k + 1 < len(costs.stamps):
            span = costs.stamps[k + 1] - costs.stamps[k]
            with np.errstate(invalid="ignore"):
                slope = np.nan_to_num((cost[k + 1] - cost[k]) / span, nan=0.0)
            pace_slope = (pace[k + 1] - pace[k]) / span
        else:
            slope = pace_slope = np.zeros(cost[k].shape)
        layers.append((cost[k].ravel().tolist(), slope.ravel().tolist(),
                       pace[k].ravel().tolist(), pace_slope.ravel().tolist()))
    return layers


def _layer_at(layers: list, stamps: list, clock: float):
    """(cost, slope, pace, pace slope) of the layer in force at `clock`, the clock span
    [low, high) where it is and the stamp its slopes start from. The costs hold before the
    first stamp (its stamp taken as +inf: no slope applies) and from the last on (slopes 0)."""
    k = bisect.bisect_right(stamps, clock) - 1
    if k < 0:
        return layers[0] + (-math.inf, stamps[0], math.inf)
    high = stamps[k + 1] if k + 1 < len(stamps) else math.inf
    return layers[k] + (stamps[k], high, stamps[k])


def _octile_to(goal: Tuple[int, int], rows: int, cols: int, floor: float) -> np.ndarray:
    """A lower bound of the cost from every cell (flat, padded) to `goal`: the 8-connected
    distance x the smallest cost per unit of length."""
    d_row = np.abs(np.arange(-1, rows + 1) - goal[0])[:, None]
    d_col = np.abs(np.arange(-1, cols + 1) - goal[1])[None, :]
    low, high = np.minimum(d_row, d_col), np.maximum(d_row, d_col)
    return (floor * (high + (math.sqrt(2.0) - 1.0) * low)).ravel()
