"""What the planner knows of the crowd: expected people per square metre on a grid of cells at a
few times (absolute clock, seconds), linear in time between them and held beyond the ends.

Grids follow nav_msgs/OccupancyGrid's layout: cell (0, 0) has its corner at `origin` and row 0
is the bottom row. A forecast of all zeros (`quiet`) stands for "no crowd model": the planner
then minimises travel time alone.
"""
import bisect
from typing import Optional, Sequence

import numpy as np

from robot_common.errors import MapError
from robot_common.maps import GridMap

__all__ = ["DensityForecast"]


class DensityForecast:
    """Expected people per square metre on a cell grid at a few times (s, absolute clock).

    Args:
        origin: (x, y) of cell (0, 0)'s corner in the map frame (m).
        resolution: cell side (m).
        times: (T,) ascending times of the grids (s).
        grids: (T, rows, cols) densities, row 0 at the bottom.
        stddev: optional (T, rows, cols) standard deviations of the densities.
    """

    def __init__(self, origin: Sequence[float], resolution: float, times, grids,
                 stddev=None):
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.times = np.atleast_1d(np.asarray(times, float))
        self.grids = np.asarray(grids, float)
        self.stddev: Optional[np.ndarray] = None if stddev is None else np.asarray(stddev, float)
        if not self.resolution > 0:
            raise MapError(f"forecast resolution must be positive, got {resolution}")
        if self.grids.ndim != 3 or self.grids.shape[0] != self.times.size or self.times.size == 0:
            raise MapError(f"forecast grids must be (times, rows, cols) with one grid per time, "
                           f"got {self.grids.shape} for {self.times.size} times")
        if np.any(np.diff(self.times) <= 0):
            raise MapError(f"forecast times must increase, got {self.times.tolist()}")
        if not np.all(np.isfinite(self.grids)) or self.grids.min() < 0:
            raise MapError("forecast densities must be finite and not negative")
        if self.stddev is not None and self.stddev.shape != self.grids.shape:
            raise MapError(f"forecast stddev shape {self.stddev.shape} differs from the "
                           f"grids' {self.grids.shape}")

    @property
    def shape(self):
        """(rows, cols) of each grid."""
        return self.grids.shape[1:]

    @classmethod
    def quiet(cls, grid: GridMap) -> "DensityForecast":
        """Nobody anywhere at any time, on the cells of `grid`."""
        return cls(grid.origin[:2], grid.resolution, [0.0], np.zeros((1,) + grid.cells.shape))

    def at(self, t: float) -> np.ndarray:
        """Densities (rows, cols) at time `t`."""
        k, share = self.bracket(t)
        if share == 0.0:
            return self.grids[k].copy()
        return (1.0 - share) * self.grids[k] + share * self.grids[k + 1]

    def bracket(self, t: float):
        """(k, share): `t` lies `share` (0..1) of the way from times[k] to times[k + 1]
        (share 0 before the first time and from the last on)."""
        k = bisect.bisect_right(self.times.tolist(), float(t)) - 1
        if k < 0:
            return 0, 0.0
        if k >= self.times.size - 1:
            return self.times.size - 1, 0.0
        return k, float((t - self.times[k]) / (self.times[k + 1] - self.times[k]))

    def cells_of(self, xy) -> tuple:
        """(row, col, inside) of the forecast cells holding points (N, 2)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        col = np.floor((xy[:, 0] - self.origin[0]) / self.resolution).astype(int)
        row = np.floor((xy[:, 1] - self.origin[1]) / self.resolution).astype(int)
        inside = (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        return row, col, inside

    def density_at(self, xy, t: float) -> np.ndarray:
        """Densities (N,) at points (N, 2) at time `t` (0 outside the grid)."""
        row, col, inside = self.cells_of(xy)
        values = np.zeros(row.size)
        values[inside] = self.at(t)[row[inside], col[inside]]
        return values

    def series_at(self, xy) -> np.ndarray:
        """Densities (T, N) at points (N, 2) at every time of the forecast (0 outside)."""
        row, col, inside = self.cells_of(xy)
        values = np.zeros((self.times.size, row.size))
        values[:, inside] = self.grids[:, row[inside], col[inside]]
        return values
