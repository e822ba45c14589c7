"""Crowd-aware paths: the cheapest way through a floor when crossing a hall costs the expected
travel time through its crowd plus a price on each person met, looked up at the time the robot is
expected to get there.

A cell is crossed at the crowd speed (Weidmann's fundamental diagram for pedestrians,
`crowd_speed`) and the robot meets the people in the band of 2 x `meet_radius` it sweeps; both
use the forecast's density averaged over the square of side 2 x `meet_radius` around the cell
(`band_forecast`: people per metre of path = that mean x the band's width; walls hold nobody, so
a narrow corridor's crowd counts whole and a path gains nothing by hugging one side of a hall).
Cost of a path = expected travel time (each second near a wall weighted as in
robot_common.gridplan's comfort term) + `person_cost` x expected people met. The search
(robot_common.gridplan.cheapest_cells, A*) carries the expected clock along: a cell's cost is the
forecast's at the time the robot would enter it; forecasts beyond `look_ahead` seconds from the
start are held.
"""
import math
from dataclasses import dataclass
from typing import Dict, Tuple

import numpy as np

from errand_nav.forecast import DensityForecast
from robot_common.errors import ConfigError
from robot_common.gridplan import CellCosts, SearchGrid, cheapest_cells, path_length
from robot_common.maps import GridMap

__all__ = ["PlannerSettings", "PlannedPath", "CrowdPlanner", "crowd_speed", "band_forecast"]


@dataclass(frozen=True)
class PlannerSettings:
    """The planner's settings (defaults written here only)."""

    cell_size: float = 0.25       # m: search cells
    clearance: float = 0.3        # m: the robot keeps this far from walls
    comfort: float = 1.0          # m: closer to a wall than this costs extra time ...
    wall_cost: float = 2.0        # ... up to this many times the time spent there
    free_speed: float = 0.6       # m/s: the controller's cruising speed in an empty hall
    jam_density: float = 5.4      # people / m^2 where the crowd stands still (Weidmann)
    crowd_gamma: float = 1.913    # m^-2: how fast the speed drops with density (Weidmann)
    min_speed: float = 0.1        # m/s: the crowd speed is never taken slower than this
    meet_radius: float = 1.0      # m: a person this close to the robot's path counts as met
    person_cost: float = 30.0     # s of travel time worth meeting one person fewer (chosen on
    #                               the generated building: bench/errand_nav/errands.py)
    look_ahead: float = 900.0     # s: forecasts beyond start + look_ahead are held

    def __post_init__(self):
        for name in ("cell_size", "clearance", "comfort", "free_speed", "jam_density",
                     "crowd_gamma", "min_speed", "meet_radius", "look_ahead"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"planner setting {name} must be positive, got "
                                  f"{getattr(self, name)}")
        for name in ("wall_cost", "person_cost"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"planner setting {name} must not be negative, got "
                                  f"{getattr(self, name)}")
        if self.min_speed > self.free_speed:
            raise ConfigError(f"min_speed {self.min_speed} exceeds free_speed {self.free_speed}")


def crowd_speed(density, settings: PlannerSettings) -> np.ndarray:
    """The robot's expected speed (m/s) at people densities (Weidmann 1993:
    v = v_free (1 - exp(-gamma (1/rho - 1/rho_jam)))), at least `min_speed`."""
    density = np.asarray(density, float)
    with np.errstate(divide="ignore"):
        spacing = np.where(density > 0, 1.0 / np.maximum(density, 1e-12), np.inf)
    share = -np.expm1(-settings.crowd_gamma * np.maximum(spacing - 1.0 / settings.jam_density,
                                                         0.0))
    return np.maximum(settings.free_speed * share, settings.min_speed)


@dataclass
class PlannedPath:
    """A path and what it is expected to cost under a forecast."""

    points: np.ndarray      # (N, 2) map frame, start .. goal
    times: np.ndarray       # (N,) expected absolute time at each point
    length: float           # m
    duration: float         # s: expected travel time
    people_met: float       # expected people within meet_radius of the robot along it
    cost: float             # duration weighted near walls + person_cost x people_met


class CrowdPlanner:
    """Plans on one map (its clearance and wall costs prepared once) under any forecast."""

    def __init__(self, grid: GridMap, settings: PlannerSettings = PlannerSettings()):
        self.grid, self.settings = grid, settings
        self.search = SearchGrid(grid, clearance=settings.clearance, comfort=settings.comfort,
                                 wall_cost=settings.wall_cost, cell_size=settings.cell_size,
                                 fine_clearance=True)
        rows, cols = np.nonzero(self.search.passable)
        self._cells = (rows, cols)
        self._centres = np.column_stack(self.search.coarse.cell_to_world(rows, cols))
        self._lookup: Dict[Tuple, Tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def plan(self, start, goal, start_time: float, forecast: DensityForecast) -> PlannedPath:
        """The cheapest path from `start` to `goal` (x, y) leaving at `start_time` (s).

        Raises robot_common.gridplan.NoPathError when either end is not clear of walls or no
        path joins them."""
        ends = [self.search.end_cell("start", start), self.search.end_cell("goal", goal)]
        band = band_forecast(forecast, self.settings.meet_radius)
        cells, _ = cheapest_cells(self._costs(start_time, band), ends[0], ends[1],
                                  float(start_time))
        return self._evaluate(self.search.polyline(cells, start, goal), start_time, band)

    def _costs(self, start_time: float, forecast: DensityForecast) -> CellCosts:
        """Cost and pace per cell side at the forecast's times within the look-ahead."""
        settings, shape = self.settings, self.search.passable.shape
        end = start_time + settings.look_ahead
        inner = [t for t in forecast.times.tolist() if start_time < t < end]
        stamps = [start_time] + inner + ([end] if forecast.times.size > 1 else [])
        density = self._densities(forecast, stamps)                       # (T, passable cells)
        pace = settings.cell_size / crowd_speed(density, settings)         # s per cell side
        extra = self.search.extra[self._cells]
        rate = pace * (1.0 + extra) + settings.person_cost * 2.0 * settings.meet_radius * \
            settings.cell_size * density
        cost_grid = np.full((len(stamps),) + shape, np.inf)
        pace_grid = np.zeros((len(stamps),) + shape)
        cost_grid[:, self._cells[0], self._cells[1]] = rate
        pace_grid[:, self._cells[0], self._cells[1]] = pace
        return CellCosts(cost_grid, pace_grid, stamps)

    def _densities(self, forecast: DensityForecast, stamps) -> np.ndarray:
        """Forecast densities (len(stamps), passable cells) at the search cells' centres."""
        key = (forecast.origin, forecast.resolution, forecast.shape)
        if key not in self._lookup:
            self._lookup = {key: forecast.cells_of(self._centres)}     # one map, one geometry
        row, col, inside = self._lookup[key]
        values = np.zeros((len(stamps), row.size))
        for k, t in enumerate(stamps):
            values[k, inside] = forecast.at(t)[row[inside], col[inside]]
        return values

    def evaluate(self, points, start_time: float, forecast: DensityForecast) -> PlannedPath:
        """Expected times, travel time, people met and cost of following `points` (N, 2) from
        `start_time` under `forecast` (the same model the search uses, sampled every half
        search cell along the path)."""
        return self._evaluate(points, start_time, band_forecast(forecast, self.settings.meet_radius))

    def _evaluate(self, points, start_time: float, forecast: DensityForecast) -> PlannedPath:
        settings = self.settings
        points = np.asarray(points, float).reshape(-1, 2)
        middles, pieces, arc = _samples(points, settings.cell_size / 2.0)
        row, col = self.search.coarse.world_to_cell(middles[:, 0], middles[:, 1])
        row = np.clip(row, 0, self.search.passable.shape[0] - 1)
        col = np.clip(col, 0, self.search.passable.shape[1] - 1)
        extra = self.search.extra[row, col]
        series = forecast.series_at(middles)                          # (T, samples)
        density = np.zeros(len(pieces))
        for _ in range(4):      # the clock depends on the densities met on the way: iterate
            seconds = pieces / crowd_speed(density, settings)
            enter = start_time + np.concatenate([[0.0], np.cumsum(seconds)[:-1]])
            density = _interpolate(series, forecast.times,
                                   np.minimum(enter + seconds / 2.0,
                                              start_time + settings.look_ahead))
        seconds = pieces / crowd_speed(density, settings)
        clock = np.concatenate([[0.0], np.cumsum(seconds)])
        people = float(np.sum(density * 2.0 * settings.meet_radius * pieces))
        times = start_time + np.interp(np.concatenate([[0.0], np.cumsum(
            np.hypot(*np.diff(points, axis=0).T))]), arc, clock)
        cost = float(np.sum(seconds * (1.0 + extra))) + settings.person_cost * people
        return PlannedPath(points, times, path_length(points), float(clock[-1]), people, cost)


def band_forecast(forecast: DensityForecast, radius: float) -> DensityForecast:
    """The forecast with each cell's density the mean over the square of side about 2 x
    `radius` around it (cells off the grid count as empty)."""
    half = int(round(radius / forecast.resolution))
    if half < 1:
        return forecast
    size = 2 * half + 1
    padded = np.pad(forecast.grids, ((0, 0), (half + 1, half), (half + 1, half)))
    total = padded.cumsum(axis=1).cumsum(axis=2)
    window = total[:, size:, size:] - total[:, :-size, size:] - total[:, size:, :-size] + \
        total[:, :-size, :-size]
    return DensityForecast(forecast.origin, forecast.resolution, forecast.times,
                           np.maximum(window / size ** 2, 0.0))


def _samples(points: np.ndarray, step: float):
    """Midpoints (M, 2) and lengths (M,) of pieces of at most `step` along the polyline, and the
    arc length (M + 1,) at the pieces' ends."""
    middles, pieces = [], []
    for a, b in zip(points[:-1], points[1:]):
        length = float(math.hypot(*(b - a)))
        if length == 0.0:
            continue
        count = max(1, int(math.ceil(length / step)))
        share = (np.arange(count) + 0.5) / count
        middles.append(a + share[:, None] * (b - a))
        pieces.append(np.full(count, length / count))
    if not pieces:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(1)
    pieces_ = np.concatenate(pieces)
    return np.vstack(middles), pieces_, np.concatenate([[0.0], np.cumsum(pieces_)])


def _interpolate(series: np.ndarray, times: np.ndarray, when: np.ndarray) -> np.ndarray:
    """series (T, M) at its own time per sample (M,): linear between times, held beyond."""
    if times.size == 1:
        return series[0].copy()
    k = np.clip(np.searchsorted(times, when, side="right") - 1, 0, times.size - 2)
    share = np.clip((when - times[k]) / (times[k + 1] - times[k]), 0.0, 1.0)
    columns = np.arange(series.shape[1])
    return (1.0 - share) * series[k, columns] + share * series[k + 1, columns]
