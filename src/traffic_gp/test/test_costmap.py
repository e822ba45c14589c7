"""Crowd cost maps: values 0..95, walls excluded, the map's own geometry."""
import numpy as np
import pytest

import traffic_gp.costmap as costmap
from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from robot_common.maps import FREE, OCCUPIED, UNKNOWN, GridMap


def test_costs_scale_with_density_and_saturate_at_95():
    costs = costmap.cost_values([0.0, 0.25, 0.5, 1.0, 3.0, np.nan, -1.0], 1.0)
    assert costs.tolist() == [0, 24, 48, 95, 95, 0, 0]
    with pytest.raises(ConfigError):
        costmap.cost_values([1.0], 0.0)


def test_full_resolution_grid_keeps_the_map_geometry_and_masks_walls():
    cells = np.full((20, 30), FREE, np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = OCCUPIED
    cells[10, 5:25] = OCCUPIED
    cells[2, 2] = UNKNOWN
    grid = CellGrid(GridMap(cells, 0.1, (1.0, 2.0, 0.0)), 4)
    costs = np.arange(grid.n_cells) % 96
    fine = costmap.upsample(grid, costs, wall_value=-1)
    assert fine.shape == cells.shape
    assert np.all(fine[cells != FREE] == -1) and np.all(fine[cells == FREE] >= 0)
    # a free map cell inside a whole model cell takes that cell's cost
    r, c = grid.rows[3], grid.cols[3]
    assert fine[r * 4 + 1, c * 4 + 1] == costs[3]
    lethal = costmap.upsample(grid, costs, wall_value=100)
    assert np.all(lethal[cells == OCCUPIED] == 100)
    coarse = costmap.coarse_grid(grid, costs)
    assert coarse.shape == grid.shape and coarse[grid.rows[5], grid.cols[5]] == costs[5]


def test_lookahead_window_times():
    np.testing.assert_allclose(costmap.window_times(10.0, 0.5, 0.25), [10.0, 10.25, 10.5])
    with pytest.raises(ConfigError):
        costmap.window_times(10.0, -1.0, 0.1)
