"""The generated building: a usable floor whose ground truth is self-consistent."""
import json

import numpy as np
import pytest
from scipy import ndimage

from robot_common.errors import ConfigError
from robot_common.gridplan import NoPathError, plan_path
from robot_common.maps import FREE, OCCUPIED, GridMap
from robot_sim import generate_building
from robot_sim.building import ROOM_KINDS, building_or_map
from robot_sim.mobile_base import PatrolPath, SensorModel, hall_patrol
from robot_sim.params import BuildingSimParams
from robot_sim.people import PeopleSimulator


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_free_space_is_one_connected_floor(seed):
    building = generate_building(seed)
    _, components = ndimage.label(building.grid.free_mask())
    assert components == 1


def test_same_seed_same_building_and_different_seed_different_rooms():
    first, again, other = generate_building(4), generate_building(4), generate_building(5)
    np.testing.assert_array_equal(first.grid.cells, again.grid.cells)
    assert first.objects == again.objects
    assert [a.label for a in first.rooms] != [a.label for a in other.rooms]


def test_objects_stand_in_free_cells_of_rooms_of_their_kind():
    building = generate_building(2)
    for obj in building.objects:
        assert building.grid.is_free(obj.x, obj.y), obj
        area = building.area_at(obj.x, obj.y)
        assert area is not None and area.name == obj.area
        if area.kind == "room":
            kind = next(k for k in ROOM_KINDS if area.label.startswith(k))
            assert obj.class_name in dict(ROOM_KINDS[kind])


def test_labels_are_in_map_labelling_format_and_inside_their_areas():
    building = generate_building(0)
    labels = json.loads(building.labels_json())
    assert {"kitchen", "water_fountain", "vending_machines"} <= set(labels)
    for name, entry in labels.items():
        assert set(entry) == {"x", "y", "orientation"} and len(entry["orientation"]) == 4
        assert building.grid.is_free(entry["x"], entry["y"]), name
    assert building.area_at(*building.labels["kitchen"]).label == "kitchen"


def test_main_hall_is_busier_than_back_hall():
    halls = {hall.name: hall for hall in generate_building(0).halls}
    assert halls["main_hall"].busy > halls["back_hall"].busy > 0


def test_patrol_stays_in_free_space_and_moves_at_its_speed():
    building = generate_building(0)
    path = hall_patrol(building, speed=0.5)
    times = np.linspace(0, path.period, 400)
    states = [path.state(t) for t in times]
    assert all(building.grid.is_free(s.x, s.y) for s in states)
    steps = [np.hypot(b.x - a.x, b.y - a.y) for a, b in zip(states, states[1:])]
    assert max(steps) <= 0.5 * (times[1] - times[0]) + 1e-9


def test_patrol_rejects_bad_paths():
    with pytest.raises(ValueError, match="at least two"):
        PatrolPath([(0, 0)], 1.0)
    with pytest.raises(ValueError, match="speed"):
        PatrolPath([(0, 0), (1, 0)], 0.0)


def test_scan_sees_the_hall_walls():
    building = generate_building(0)
    sensors = SensorModel(building.grid, scan_beams=181)
    path = hall_patrol(building)
    state = path.state(1.0)
    ranges = sensors.scan(state)
    main = building.halls[0]
    # Driving east along the hall, away from any door: beams straight left and right end at the
    # hall's walls.
    assert state.yaw == 0.0 and all(abs(state.x - room.centre[0]) > 0.6 for room in building.rooms)
    left = ranges[np.argmin(np.abs(sensors.scan_angles - np.pi / 2))]
    right = ranges[np.argmin(np.abs(sensors.scan_angles + np.pi / 2))]
    assert left == pytest.approx(main.box[3] - state.y, abs=0.1)
    assert right == pytest.approx(state.y - main.box[1], abs=0.1)
    assert sensors.image(state).shape == (240, 320, 3)


# The loop floor (generate_building(seed, loop=True)). Worked out by hand for the defaults
# (5 rooms a side, 5 m rooms, 3 m main hall, 2 m back hall, 0.2 m walls, 0.1 m cells): the default
# floor is 27.4 m x 13.4 m (274 x 134 cells) from (0, 0); the loop floor grows 2.5 m west (the
# 2.2 m of corridor and wall rounded up to whole 0.5 m people cells) and 2.2 m north, so it is
# 29.9 m x 15.6 m (299 x 156 cells) from (-2.5, 0); the old floor sits at columns 25 on.
WEST_END, BACK_HALL = (1.7, 6.7), (26.2, 6.7)


def _with_wall(grid, box):
    cells = grid.cells.copy()
    (r0, c0), (r1, c1) = [grid.world_to_cell(x, y) for x, y in ((box[0], box[1]), (box[2], box[3]))]
    cells[r0:r1, c0:c1] = OCCUPIED
    return GridMap(cells, grid.resolution, grid.origin)


def test_the_default_floor_is_the_same_with_the_loop_option_off():
    for seed in (0, 3):
        default, off = generate_building(seed), generate_building(seed, loop=False)
        assert default.grid.cells.shape == (134, 274) and default.grid.origin == (0.0, 0.0, 0.0)
        np.testing.assert_array_equal(off.grid.cells, default.grid.cells)
        assert off.grid.origin == default.grid.origin and off.grid.meta == default.grid.meta
        assert off.labels == default.labels and off.areas == default.areas
        assert off.objects == default.objects


def test_the_loop_floor_keeps_every_room_label_and_object_where_it_was():
    default, loop = generate_building(3), generate_building(3, loop=True)
    assert loop.grid.cells.shape == (156, 299) and loop.grid.origin == (-2.5, 0.0, 0.0)
    assert loop.labels == default.labels and loop.objects == default.objects
    assert loop.rooms == default.rooms
    halls = {area.name: area for area in loop.halls}
    assert halls["main_hall"] == default.halls[0]
    assert halls["back_hall"].box == (25.2, 0.2, 27.2, 13.4)       # up through its north wall
    assert halls["west_corridor"].box == (-2.0, 5.2, 0.0, 13.4)
    assert halls["north_corridor"].box == (-2.0, 13.4, 27.2, 15.4)
    assert halls["west_corridor"].busy == halls["north_corridor"].busy == 0.3
    # The old floor, cell for cell, but for the two openings into the loop, freed: the main
    # hall's west wall (columns 0-1, x 0-0.2 m) on the rows where the main hall is free (a column
    # inside it, x 1.0 m, between the rooms' walls at y 5.0 and 8.4 m), and the back hall's
    # north wall over the back hall's free columns (x 25.2-27.2 m, from its wall's east side at
    # x 25.0 m) from its last free row to the map's top.
    changed = loop.grid.cells[:134, 25:] != default.grid.cells
    assert (loop.grid.cells[:134, 25:][changed] == FREE).all()
    hall_rows = np.nonzero(default.grid.cells[50:84, 10] == FREE)[0] + 50
    back_cols = np.nonzero(default.grid.cells[100, 250:] == FREE)[0] + 250
    back_rows = np.arange(np.nonzero(default.grid.cells[:, 260] == FREE)[0].max() + 1, 134)
    assert 29 <= len(hall_rows) <= 30 and 2 <= len(back_rows) <= 3     # 3 m and 0.2 m, +-1 row
    assert 20 <= len(back_cols) <= 21 and back_cols[-1] == 271         # 2 m, +-1 column
    expected = np.zeros_like(changed)
    expected[hall_rows, 0:2] = True
    expected[back_rows[:, None], back_cols] = True
    np.testing.assert_array_equal(changed, expected)
    _, components = ndimage.label(loop.grid.free_mask())
    assert components == 1
    free = loop.grid.free_mask()
    assert free[100, :25].sum() == 20 and free[134:, 100].sum() == 20    # 2 m wide corridors
    assert free[140, 5:297].all() and not free[140, 297:].any()     # x -2.0 to 27.2 m


def test_only_the_loop_floor_has_a_way_round_a_blocked_main_hall():
    block = (12.0, 5.2, 13.0, 8.2)        # a wall across the main hall
    path = plan_path(_with_wall(generate_building(0, loop=True).grid, block), WEST_END, BACK_HALL)
    assert path[:, 0].min() < 0.0 and path[:, 1].max() > 13.4   # by the west and north corridors
    with pytest.raises(NoPathError):
        plan_path(_with_wall(generate_building(0).grid, block), WEST_END, BACK_HALL)


def test_the_new_corridors_are_quiet_while_the_main_hall_is_busy_at_a_rush():
    building = generate_building(0, loop=True)
    sim = PeopleSimulator.from_building(building, 0.5)
    expected = sim.expected_count(10.0 + 50 / 60)[0]          # Monday 10:50, before a class
    per_cell = {}
    for area in building.halls:
        x0, y0, x1, y1 = area.box
        inside = (sim.cells.x >= x0) & (sim.cells.x <= x1) & (sim.cells.y >= y0) & (sim.cells.y <= y1)
        assert inside.sum() > 10 and (sim.layout.hall[inside] >= 0).all()
        per_cell[area.name] = expected[inside].mean()
    assert sim.layout.main.sum() > 0 and \
        set(sim.layout.names[i] for i in sim.layout.hall[sim.layout.main]) == {"main_hall"}
    # busy 0.3 against 1.0 and no class doors: well under a third of the main hall's people.
    for name in ("west_corridor", "north_corridor"):
        assert 0 < per_cell[name] < per_cell["main_hall"] / 3, per_cell


def test_building_or_map_gives_the_asked_layout_and_refuses_others():
    grid, building = building_or_map("", 0, "loop")
    assert grid.origin[0] < 0 and "north_corridor" in {area.name for area in building.halls}
    assert building_or_map("", 0)[0].origin == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="layout"):
        building_or_map("", 0, "ring")
    with pytest.raises(ConfigError, match="layout"):
        BuildingSimParams.from_mapping({"layout": "ring"})
