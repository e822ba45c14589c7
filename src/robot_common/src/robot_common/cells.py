"""Cells and time: the shared vocabulary of everything counted per place and hour (no ROS).

Space is cut into square cells (`CellGrid`: a map downsampled with `GridMap.downsample`, walls and
unknown cells masked out; free cells indexed 0..n-1). Time is hours since Monday 00:00
(`hours_of_week` converts UNIX time). A `View` is what one robot saw from one place: the cells in
view (`visible_cells`, ray cast in the map), the seen part of each cell and the people counted
there, so "seen, nobody there" (count 0) differs from "not seen" (absent).

Counts over a watch of `duration` seconds include people who walked in meanwhile: the expected
count in a cell is `density * seen_area * (1 + duration / dwell_time)` (`exposure`).
"""
import datetime
import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from robot_common.errors import MapError
from robot_common.maps import GridMap, raycast

__all__ = ["DWELL_TIME_S", "HOURS_PER_WEEK", "hours_of_week", "exposure", "CellGrid",
           "visible_cells", "View"]

DWELL_TIME_S = 20.0   # seconds a person stays in view of one cell, on average
HOURS_PER_WEEK = 168.0


def hours_of_week(unix_seconds, utc_offset_hours: Optional[float] = None):
    """Hours since Monday 00:00 (0 <= h < 168) of UNIX times, in the given or the local zone."""
    unix_seconds = np.asarray(unix_seconds, dtype=float)
    if utc_offset_hours is None:
        first = float(unix_seconds.ravel()[0]) if unix_seconds.size else 0.0
        offset = datetime.datetime.fromtimestamp(first).astimezone().utcoffset()
        utc_offset_hours = offset.total_seconds() / 3600.0 if offset else 0.0
    # 1970-01-01 was a Thursday: 3 days after a Monday.
    hours = unix_seconds / 3600.0 + utc_offset_hours + 72.0
    return np.mod(hours, HOURS_PER_WEEK)


def exposure(seen_area, duration_s=0.0, dwell_time_s: float = DWELL_TIME_S):
    """Effective watched area (m^2): the expected count is density * exposure."""
    return np.asarray(seen_area, dtype=float) * (1.0 + np.asarray(duration_s, float) / dwell_time_s)


@dataclass
class CellGrid:
    """The cells people are counted in: `grid` downsampled by `factor`; free cells indexed 0..n-1."""

    grid: GridMap
    factor: int

    def __post_init__(self):
        self.coarse = self.grid.downsample(self.factor)
        self.rows, self.cols = np.nonzero(self.coarse.free_mask())
        if self.rows.size == 0:
            raise MapError("the map has no free cell at this cell size")
        self.x, self.y = self.coarse.cell_to_world(self.rows, self.cols)
        self._index = np.full(self.coarse.cells.shape, -1, dtype=np.int64)
        self._index[self.rows, self.cols] = np.arange(self.rows.size)

    @classmethod
    def from_map(cls, grid: GridMap, cell_size: float) -> "CellGrid":
        """Cells of about `cell_size` metres (a whole number of map cells, at least one)."""
        if not cell_size > 0:
            raise MapError(f"cell_size must be positive, got {cell_size}")
        return cls(grid, max(1, int(round(cell_size / grid.resolution))))

    @property
    def n_cells(self) -> int:
        return int(self.rows.size)

    @property
    def cell_size(self) -> float:
        return self.coarse.resolution

    @property
    def cell_area(self) -> float:
        return self.coarse.resolution ** 2

    @property
    def shape(self) -> Tuple[int, int]:
        return self.coarse.cells.shape

    def index_at(self, x, y) -> np.ndarray:
        """Index of the free cell holding each world point; -1 for walls, unknown, outside."""
        row, col = self.coarse.world_to_cell(x, y)
        inside = self.coarse.inside(row, col)
        result = np.full(np.shape(row), -1, dtype=np.int64)
        result[inside] = self._index[row[inside], col[inside]]
        return result

    def to_image(self, values, fill=np.nan) -> np.ndarray:
        """Per-cell values as a 2-D array over the coarse grid (row 0 at the origin)."""
        image = np.full(self.shape, fill, dtype=float)
        image[self.rows, self.cols] = values
        return image


def visible_cells(cells: CellGrid, x: float, y: float, radius: float, *, n_rays: int = 180,
                  sub: int = 3, vis_grid: Optional[GridMap] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Cells seen from (x, y) within `radius` (360 degrees, walls block the view).

    Returns (cell indices, seen fraction of each cell's area), fractions in (0, 1]; a cell's
    fraction is the share of its `sub` x `sub` sample points in view.
    """
    vis_grid = vis_grid if vis_grid is not None else cells.grid
    angles = np.linspace(-math.pi, math.pi, n_rays, endpoint=False)
    ranges = raycast(vis_grid, x, y, angles, radius)
    reach = radius + cells.cell_size
    near = np.nonzero((np.abs(cells.x - x) <= reach) & (np.abs(cells.y - y) <= reach))[0]
    if near.size == 0:
        return near, np.zeros(0)
    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    dx = cells.x[near, None, None] + offsets[None, :, None] * cells.cell_size - x
    dy = cells.y[near, None, None] + offsets[None, None, :] * cells.cell_size - y
    dist = np.hypot(dx, dy)
    ray = np.round((np.arctan2(dy, dx) + math.pi) / (2 * math.pi) * n_rays).astype(int) % n_rays
    seen = (dist <= np.minimum(ranges[ray], radius)).reshape(near.size, -1).mean(axis=1)
    keep = seen > 0
    return near[keep], seen[keep]


@dataclass
class View:
    """What one robot saw: the cells in view, their seen fraction, and people counted in each."""

    robot_id: str
    t: float             # hours since Monday 00:00 of the first simulated week
    x: float
    y: float
    duration: float      # seconds watched
    cells: np.ndarray
    fractions: np.ndarray
    counts: np.ndarray
