"""Answers the node serves, computed from a fitted model and the map's cells (no ROS).

`CrowdQueries` answers "how many people at this place and time", "how many in this region",
"what density over the whole map at these times" (for planners that look ahead), and builds
crowd cost maps over a look-ahead window. Times are hours since Monday 00:00.
"""
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

import traffic_gp.costmap as costmap
import traffic_gp.predictive as predictive
from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from traffic_gp.errors import TrafficError
from traffic_gp.posterior import latent_grid

MAX_JOINT_CELLS = 1500   # above this, region sums treat cells as independent
MAX_DENSITY_TIMES = 48   # times in one `density_grids` call
NO_SPREAD = 1e-10        # latent variance at most this: a point forecast, no standard deviation


@dataclass
class Estimate:
    expected: float       # expected people
    stddev: float         # uncertainty of `expected`
    lower: float          # 90% interval (of the count for a cell, of the expected sum for a region)
    upper: float
    density: float        # people per m^2
    cells: int
    area: float


def polygon_mask(cells: CellGrid, polygon: Sequence[Tuple[float, float]]) -> np.ndarray:
    """Cells whose centres lie inside `polygon` (x, y vertices); all cells when it is empty."""
    if len(polygon) == 0:
        return np.ones(cells.n_cells, bool)
    if len(polygon) < 3:
        raise ConfigError(f"a region needs at least 3 vertices, got {len(polygon)}")
    from matplotlib.path import Path

    return Path(np.asarray(polygon, float)).contains_points(np.column_stack([cells.x, cells.y]))


class CrowdQueries:
    """Predictions over a map's cells from a fitted `TrafficGP` (or anything with its methods;
    `predict_latent_grid` is optional: a saved posterior's is the fast one)."""

    def __init__(self, model, cells: CellGrid, *, level: float = 0.9, n_samples: int = 400):
        self.model, self.cells, self.level, self.n_samples = model, cells, level, n_samples

    def at(self, x: float, y: float, hours: float) -> Estimate:
        """People expected in the cell holding (x, y) at `hours`."""
        index = int(self.cells.index_at(np.array([x]), np.array([y]))[0])
        if index < 0:
            raise TrafficError(f"({x:.2f}, {y:.2f}) is not in a free cell of the map")
        cx, cy, area = self.cells.x[index], self.cells.y[index], self.cells.cell_area
        mean, var = self.model.predict_latent(cx, cy, hours)
        low, high = predictive.interval(self.level, mean, var, area,
                                        getattr(self.model, "count_dispersion_", None))
        density = float(predictive.expected_value(mean, var)[0])
        return Estimate(density * area, float(predictive.expected_std(mean, var)[0]) * area,
                        float(low[0]), float(high[0]), density, 1, area)

    def region(self, polygon: Sequence[Tuple[float, float]], hours: float,
               rng: Optional[np.random.Generator] = None) -> Estimate:
        """People expected in the free cells of `polygon` at `hours` (joint over the cells)."""
        inside = np.nonzero(polygon_mask(self.cells, polygon))[0]
        if inside.size == 0:
            raise TrafficError("the region holds no free cell of the map")
        x, y, area = self.cells.x[inside], self.cells.y[inside], self.cells.cell_area
        mean, var = self.model.predict_latent(x, y, np.full(inside.size, hours))
        expected = float(np.sum(predictive.expected_value(mean, var)) * area)
        if inside.size <= MAX_JOINT_CELLS:
            totals = self.model.sample_totals(x, y, np.full(inside.size, hours), area,
                                              self.n_samples)
            stddev = float(np.std(totals))
            tail = (1.0 - self.level) / 2.0
            low, high = np.quantile(totals, [tail, 1.0 - tail])
        else:
            stddev = float(np.sqrt(np.sum(predictive.expected_std(mean, var) ** 2)) * area)
            low, high = max(expected - 1.645 * stddev, 0.0), expected + 1.645 * stddev
        total_area = inside.size * area
        return Estimate(expected, stddev, float(low), float(high), expected / total_area,
                        int(inside.size), total_area)

    def _latent(self, times) -> Tuple[np.ndarray, np.ndarray]:
        """Mean and variance of the log density of every cell at each time: (len(times), n_cells)."""
        grid = getattr(self.model, "predict_latent_grid", None)   # optional (see the class)
        if grid is None:
            return latent_grid(self.model.predict_latent, self.cells.x, self.cells.y, times)
        return grid(self.cells.x, self.cells.y, times)

    def densities(self, times: Sequence[float]) -> np.ndarray:
        """Expected density of every cell at each time: shape (len(times), n_cells)."""
        return predictive.expected_value(*self._latent(times))

    def density_grids(self, times: Sequence[float]) -> Tuple[np.ndarray, np.ndarray]:
        """Expected density (people per m^2) over the cell grid (`cells.coarse`, row 0 at its
        origin) at each time, and its standard deviation: arrays (len(times), rows, cols).
        Cells outside the model (a wall or unknown space in the cell) have density 0 and
        standard deviation NaN; so do point forecasts (latent variance at most NO_SPREAD: a
        baseline without a calibrated width, a place nobody can reach)."""
        times = np.asarray(times, float).ravel()
        if not 1 <= times.size <= MAX_DENSITY_TIMES:
            raise TrafficError(f"{times.size} times asked: give 1 to {MAX_DENSITY_TIMES}")
        if not np.all(np.isfinite(times)):
            raise TrafficError(f"times must be finite, got {times.tolist()}")
        mean, var = self._latent(times)
        spread = np.where(var > NO_SPREAD, predictive.expected_std(mean, var), np.nan)
        density = np.zeros((times.size,) + self.cells.shape)
        stddev = np.full(density.shape, np.nan)
        density[:, self.cells.rows, self.cells.cols] = predictive.expected_value(mean, var)
        stddev[:, self.cells.rows, self.cells.cols] = spread
        return density, stddev

    def cost_grid(self, now: float, *, lookahead_hours: float, step_hours: float,
                  saturation_density: float, wall_value: int = -1,
                  full_resolution: bool = True) -> Tuple[np.ndarray, np.ndarray]:
        """(cost grid for `now`, cost grid for the maximum over [now, now + look-ahead])."""
        dens = self.densities(costmap.window_times(now, lookahead_hours, step_hours))
        grids = []
        for values in (dens[0], dens.max(axis=0)):
            costs = costmap.cost_values(values, saturation_density)
            grids.append(costmap.upsample(self.cells, costs, wall_value) if full_resolution
                         else costmap.coarse_grid(self.cells, costs, wall_value))
        return grids[0], grids[1]
