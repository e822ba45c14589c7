"""The grid planner: shortest free paths, kept off walls, refusing what cannot be reached."""
import numpy as np
import pytest

from robot_common.gridplan import NoPathError, clearance_map, path_length, plan_path
from robot_common.maps import FREE, OCCUPIED, GridMap


def walled_room():
    """A 6 m x 4 m room (0.1 m cells) with a wall across x = 3 m, open only for y in 3-4 m."""
    cells = np.full((40, 60), FREE, dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    cells[:29, 29:31] = OCCUPIED
    return GridMap(cells, 0.1)


def test_the_path_goes_round_the_wall_through_the_gap():
    grid = walled_room()
    path = plan_path(grid, (1.0, 1.0), (5.0, 1.0), clearance=0.3, comfort=0.3, cell_size=0.1)
    assert tuple(path[0]) == (1.0, 1.0) and tuple(path[-1]) == (5.0, 1.0)
    # the wall ends at y = 2.9 m: the path must climb past it (straight line: 4 m)
    assert path[:, 1].max() > 2.9 + 0.3 - 0.1
    assert 6.0 < path_length(path) < 8.0
    assert grid.is_free(path[:, 0], path[:, 1]).all()


def test_clearance_grows_by_a_cell_per_cell_from_the_wall():
    grid = walled_room()
    distance = clearance_map(grid, 1.0)
    # row 20 (y = 2.05 m), columns 28, 27, 26 are 1, 2, 3 cells left of the wall (column 29)
    assert distance[20, 28:25:-1].tolist() == pytest.approx([0.1, 0.2, 0.3])


def test_an_unreachable_goal_is_refused_with_the_reason():
    grid = walled_room()
    grid.cells[:, 29:31] = OCCUPIED                    # close the gap
    with pytest.raises(NoPathError, match="no free path"):
        plan_path(grid, (1.0, 1.0), (5.0, 1.0), clearance=0.3, cell_size=0.1)
    with pytest.raises(NoPathError, match="goal"):
        plan_path(grid, (1.0, 1.0), (3.0, 1.0), clearance=0.3, cell_size=0.1)
