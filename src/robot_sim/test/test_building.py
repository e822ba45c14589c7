"""The generated building: a usable floor whose ground truth is self-consistent."""
import json

import numpy as np
import pytest
from scipy import ndimage

from robot_sim import generate_building
from robot_sim.building import ROOM_KINDS
from robot_sim.mobile_base import PatrolPath, SensorModel, hall_patrol


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
