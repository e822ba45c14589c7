"""Crowd cost maps as occupancy grids a costmap_2d static layer can use (NumPy, no ROS).

Cost: 95 x min(1, density / saturation_density), density the expected people per m^2 (so the
value does not depend on the cell size); the maximum over [now, now + look-ahead] when several
times are given. Cells where people cannot be (walls, unknown space) get `wall_value`:
-1 (default): with `track_unknown_space: false` the static layer reads -1 as free space, with
`track_unknown_space: true` as NO_INFORMATION, which `use_maximum: true` skips; either way the
crowd layer leaves walls to the map's own static layer. 100 would mark them lethal instead.

The grid can be published at the map's own resolution (`upsample`, the default of the node): a
costmap_2d static layer resizes the whole layered costmap to the size and resolution of the map
it receives, so a coarse crowd grid would coarsen the robot's costmap.
"""
from typing import Sequence

import numpy as np
from scipy import ndimage

from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from robot_common.maps import FREE

MAX_COST = 95


def cost_values(density, saturation_density: float) -> np.ndarray:
    """Costs 0..95 (int8) from expected densities (people per m^2)."""
    if not saturation_density > 0:
        raise ConfigError(f"saturation_density must be positive, got {saturation_density}")
    density = np.nan_to_num(np.asarray(density, dtype=float), nan=0.0)
    return np.clip(np.round(MAX_COST * density / saturation_density), 0, MAX_COST).astype(np.int8)


def window_times(now: float, lookahead_hours: float, step_hours: float) -> np.ndarray:
    """Times now, now + step, ..., now + look-ahead (hours)."""
    if lookahead_hours < 0 or not step_hours > 0:
        raise ConfigError(f"bad look-ahead {lookahead_hours} h / step {step_hours} h")
    return now + np.arange(0.0, lookahead_hours + 1e-9, step_hours)


def coarse_grid(cells: CellGrid, costs: Sequence[int], wall_value: int = -1) -> np.ndarray:
    """Costs over the cell grid (row 0 at the origin); non-cells get `wall_value`."""
    grid = np.full(cells.shape, wall_value, dtype=np.int8)
    grid[cells.rows, cells.cols] = costs
    return grid


def upsample(cells: CellGrid, costs: Sequence[int], wall_value: int = -1) -> np.ndarray:
    """Costs over the original map's cells: each free map cell takes its cell's cost, or the
    nearest cell's where its cell was masked (cells touching a wall are masked when
    downsampling); walls and unknown map cells get `wall_value`."""
    values = np.zeros(cells.shape)
    valid = np.zeros(cells.shape, bool)
    values[cells.rows, cells.cols] = costs
    valid[cells.rows, cells.cols] = True
    _, (near_r, near_c) = ndimage.distance_transform_edt(~valid, return_indices=True)
    filled = values[near_r, near_c]
    fine = cells.grid
    rows = np.minimum(np.arange(fine.height) // cells.factor, cells.shape[0] - 1)
    cols = np.minimum(np.arange(fine.width) // cells.factor, cells.shape[1] - 1)
    out = filled[rows[:, None], cols[None, :]].astype(np.int8)
    out[fine.cells != FREE] = wall_value
    return out
