"""GridMap, map_server file I/O and ray casting, without ROS."""
import math

import numpy as np
import pytest
from PIL import Image

from robot_common import FREE, OCCUPIED, UNKNOWN, GridMap, MapError, load_map, raycast, save_map
from robot_common.maps import unmapped


def write_map(tmp_path, pixels, **meta):
    Image.fromarray(np.asarray(pixels, dtype=np.uint8), mode="L").save(tmp_path / "m.pgm")
    fields = {"image": "m.pgm", "resolution": 0.5, "origin": [-1.0, 2.0, 0.0], "negate": 0,
              "occupied_thresh": 0.65, "free_thresh": 0.196}
    fields.update(meta)
    (tmp_path / "m.yaml").write_text("\n".join(f"{k}: {v}" for k, v in fields.items()))
    return tmp_path / "m.yaml"


def test_load_applies_map_server_thresholds_and_flips_rows(tmp_path):
    # map_server: occupancy = (255 - pixel) / 255; > occupied_thresh occupied, < free_thresh free.
    # The image's first row is the top of the map, so it becomes the last grid row.
    path = write_map(tmp_path, [[0, 254, 205], [255, 100, 89]])
    grid = load_map(path)
    assert grid.cells.tolist() == [[FREE, UNKNOWN, OCCUPIED], [OCCUPIED, FREE, UNKNOWN]]
    assert grid.resolution == 0.5 and grid.origin == (-1.0, 2.0, 0.0)


def test_negate_inverts_pixels(tmp_path):
    grid = load_map(write_map(tmp_path, [[0, 255]], negate=1))
    assert grid.cells.tolist() == [[FREE, OCCUPIED]]


def test_save_then_load_gives_the_same_cells(tmp_path):
    rng = np.random.default_rng(3)
    cells = rng.choice([FREE, OCCUPIED, UNKNOWN], size=(17, 23)).astype(np.int8)
    grid = GridMap(cells, 0.05, (1.5, -2.0, 0.0))
    loaded = load_map(save_map(grid, tmp_path / "out" / "saved.yaml"))
    np.testing.assert_array_equal(loaded.cells, cells)
    assert loaded.resolution == pytest.approx(0.05) and loaded.origin == (1.5, -2.0, 0.0)


def test_world_and_cell_coordinates_invert_each_other():
    grid = GridMap(np.zeros((10, 20)), 0.25, (-2.0, 1.0, 0.0))
    row, col = grid.world_to_cell(-2.0 + 0.25 * 7.5, 1.0 + 0.25 * 3.5)
    assert (int(row), int(col)) == (3, 7)
    x, y = grid.cell_to_world(3, 7)
    assert (x, y) == pytest.approx((-2.0 + 0.25 * 7.5, 1.0 + 0.25 * 3.5))
    assert not grid.is_free(-3.0, 0.0) and grid.is_free(x, y)


def test_downsample_is_conservative():
    cells = np.zeros((4, 4), dtype=np.int8)
    cells[0, 0] = OCCUPIED
    cells[3, 3] = UNKNOWN
    coarse = GridMap(cells, 0.1).downsample(2)
    assert coarse.cells.tolist() == [[OCCUPIED, FREE], [FREE, UNKNOWN]]
    assert coarse.resolution == pytest.approx(0.2)


def test_raycast_measures_distance_to_the_walls_of_a_box():
    cells = np.full((100, 100), OCCUPIED, dtype=np.int8)
    cells[1:99, 1:99] = FREE  # free interior from 0.1 m to 9.9 m
    grid = GridMap(cells, 0.1)
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2])
    ranges = raycast(grid, 3.0, 4.0, angles, max_range=20.0)
    # Walls begin at 9.9 (east, north) and end at 0.1 (west, south); half-cell sampling.
    np.testing.assert_allclose(ranges, [6.9, 5.9, 2.9, 3.9], atol=0.06)
    assert raycast(grid, 3.0, 4.0, np.array([0.0]), max_range=2.0)[0] == pytest.approx(2.0)


def test_real_building_map_loads(shared_data_dir):
    grid = load_map(shared_data_dir / "maps" / "levine_6th.yaml")
    assert (grid.width, grid.height) == (665, 589)
    assert grid.resolution == pytest.approx(0.035)
    free = grid.free_mask().mean()
    assert 0.05 < free < 0.5, free


@pytest.mark.parametrize("content, message", [
    ("image: m.pgm\n", "lacks resolution, origin"),
    ("[1, 2", "cannot read map file"),
    ("image: missing.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", "cannot read map image"),
])
def test_bad_map_files_give_clear_errors(tmp_path, content, message):
    (tmp_path / "bad.yaml").write_text(content)
    with pytest.raises(MapError, match=message):
        load_map(tmp_path / "bad.yaml")


def test_a_ray_enters_and_leaves_the_first_disc_in_its_way():
    from robot_common.maps import ray_disc_hits

    centres = np.array([[4.0, 0.0], [2.0, 0.0]])
    entry, exit_ = ray_disc_hits(0.0, 0.0, np.array([0.0, math.pi]), centres, 0.5)
    # along +x: the disc at 2 m (not the one at 4 m) from 1.5 to 2.5 m; along -x: nothing
    assert entry[0] == pytest.approx(1.5) and exit_[0] == pytest.approx(2.5)
    assert np.isinf(entry[1]) and np.isinf(exit_[1])
    # a ray from inside the disc at (0, 0.2), along +y: entered 0.3 m behind, left 0.7 m ahead
    entry, exit_ = ray_disc_hits(0.0, 0.0, np.array([math.pi / 2]), np.array([[0.0, 0.2]]), 0.5)
    assert entry[0] == pytest.approx(-0.3) and exit_[0] == pytest.approx(0.7)
    none, _ = ray_disc_hits(0.0, 0.0, np.array([0.0]), np.zeros((0, 2)), 0.5)
    assert np.isinf(none).all()


def test_a_point_falls_in_the_beam_that_points_at_it():
    from robot_common.maps import beam_indices

    angles = np.linspace(-math.pi / 2, math.pi / 2, 5)     # beams every 45 degrees, facing +y
    # a sensor at (1, 1) facing +y: (1, 3) is straight ahead (beam 2), (3, 1) on its right
    # (beam 0), (1, -1) behind it (outside the field of view)
    beams = beam_indices((1.0, 1.0, math.pi / 2), angles, [1.0, 3.0, 1.0], [3.0, 1.0, -1.0])
    assert beams.tolist() == [2, 0, -1]


def test_a_beam_reaches_its_return_the_range_max_without_one_and_nothing_when_invalid():
    from robot_common.maps import beam_reach

    ranges = [2.0, float("inf"), 8.0, 9.5, float("nan"), 0.05, float("-inf")]
    assert beam_reach(ranges, 0.1, 8.0).tolist() == [2.0, 8.0, 8.0, 8.0, 0.0, 0.0, 0.0]


def test_a_point_is_seen_past_only_when_the_beams_by_it_all_reach_beyond_it():
    from robot_common.maps import seen_through

    angles = np.radians(np.arange(-90.0, 91.0, 1.0))          # every degree, facing +x
    reach = np.full(len(angles), 5.0)
    reach[90] = 2.0                                             # a return straight ahead at 2 m
    reach[120] = 3.0                                            # and one at 30 degrees, 3 m
    at30 = np.array([math.cos(math.radians(30.0)), math.sin(math.radians(30.0))])
    points = np.array([[1.0, 0.0],          # short of the return ahead: seen past
                       [2.0, 0.0],          # the return itself: not
                       [3.0, 0.0],          # behind it: not
                       [-1.0, 0.0],         # behind the sensor, outside the field of view: not
                       [0.0, 4.95],         # within 0.1 m of the beams' reach: not
                       [0.0, 4.0],          # at the last beam, well inside its reach: seen past
                       *(2.95 * at30[None]),    # in the beam beside one returning at 3 m: not
                       *(1.5 * at30[None])])
    assert seen_through((0.0, 0.0, 0.0), angles, reach, points, 0.1).tolist() == [
        True, False, False, False, False, True, False, True]
    # the beam at 31 degrees holds (2.9 cos 31, 2.9 sin 31); its neighbour at 30 returns at 3 m
    near = 2.95 * np.array([math.cos(math.radians(31.0)), math.sin(math.radians(31.0))])
    assert not seen_through((0.0, 0.0, 0.0), angles, reach, near[None], 0.1)[0]
    assert seen_through((0.0, 0.0, 0.0), angles, reach, np.zeros((0, 2))).shape == (0,)


def test_only_scan_points_the_map_does_not_explain_are_unmapped():
    cells = np.full((40, 40), FREE, dtype=np.int8)
    cells[:, 30:] = OCCUPIED                                   # a wall from x = 3.0 m
    grid = GridMap(cells, 0.1)
    points = np.array([[2.99, 1.0], [2.0, 1.0], [2.9, 2.0]])   # on the wall, in the hall, near it
    assert unmapped(grid, points, 0.15).tolist() == [False, True, False]


def test_a_return_past_a_wall_thinner_than_the_margin_is_that_wall():
    cells = np.full((80, 80), FREE, dtype=np.int8)
    cells[:, 40:42] = OCCUPIED                      # a wall 0.1 m thick at x = 2.0 m on 0.05 m cells
    grid = GridMap(cells, 0.05)
    points = np.array([[2.14, 1.0], [2.5, 1.0]])    # just past the wall, well past it
    # 3 x 3 samples 0.15 m apart step over it: only every cell within the margin sees it
    assert unmapped(grid, points, 0.15).tolist() == [False, True]
