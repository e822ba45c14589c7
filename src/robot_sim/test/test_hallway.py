"""Building scenes: routes along the halls, people of each kind, the laser and the tracker, and
drives that end at the goal or at what the robot touches."""
import math
import os

import numpy as np
import pytest

from robot_common.gridplan import path_length
from robot_common.maps import load_map
from robot_sim.building import generate_building
from robot_sim.errors import SimError
from robot_sim.hallway import (
    PEOPLE_KINDS,
    PERSON_RADIUS,
    HallwayScene,
    Walker,
    drive,
    make_scene,
)

MAPS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "..", "shared", "data", "maps")


@pytest.fixture(scope="module")
def grid():
    return generate_building(0).grid


def test_a_scene_has_a_hallway_route_of_the_asked_length_and_its_people(grid):
    scene = make_scene(grid, 3, people=6, clutter=1)
    assert 10.0 <= path_length(scene.path) <= 60.0
    assert grid.is_free(scene.path[:, 0], scene.path[:, 1]).all()
    assert len(scene.people) == 6 and {w.kind for w in scene.people} <= set(PEOPLE_KINDS)
    assert scene.collision(scene.start, 0.0) is None
    assert len(scene.clutter) == 1


def test_every_people_kind_can_be_asked_for(grid):
    for kind in PEOPLE_KINDS:
        scene = make_scene(grid, 1, people=2, clutter=0, kinds=(kind,))
        assert {w.kind for w in scene.people} <= {kind, "head_on"}   # a group with no room walks
    with pytest.raises(SimError, match="0-8 people"):
        make_scene(grid, 1, people=9)
    with pytest.raises(SimError, match="kinds"):
        make_scene(grid, 1, kinds=("dancing",))


def open_scene(people, clutter=()):
    """A 10 m x 4 m empty room (0.1 m cells), the path along y = 2 m from x = 1 to 9 m."""
    from robot_common.maps import FREE, OCCUPIED, GridMap
    cells = np.full((40, 100), FREE, dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    path = np.column_stack([np.linspace(1, 9, 81), np.full(81, 2.0)])
    return HallwayScene(GridMap(cells, 0.1), path, np.array([1.0, 2.0, 0.0, 0.0, 0.0]), people,
                        np.array(clutter, float).reshape(-1, 3))


def test_the_laser_sees_walls_people_and_clutter():
    standing = Walker("p0", "group", np.array([[4.0, 2.0]]))
    scene = open_scene([standing], clutter=[(1.0, 3.0, 0.3)])
    angles = np.array([0.0, math.pi / 2, math.pi])
    ranges = scene.scan((1.0, 2.0, 0.0), 0.0, angles, 8.0)
    # ahead the person's edge at 4 - 0.25 - 1 = 2.75 m; left the clutter's edge at 1 - 0.3 m;
    # behind the wall cell at x < 0.1 m, reached at 0.9-0.95 m (half-cell ray steps)
    assert ranges[0] == pytest.approx(3.0 - PERSON_RADIUS)
    assert ranges[1] == pytest.approx(0.7)
    assert 0.85 <= ranges[2] <= 0.95


def test_the_tracker_reports_positions_and_velocities_of_people_in_sight():
    walking = Walker("p1", "head_on", np.array([[8.0, 2.5], [2.0, 2.5]]), speed=1.0)
    scene = open_scene([walking])
    names, positions, velocities = scene.tracked((1.0, 2.0, 0.0), 2.0)
    assert names == ["p1"]
    np.testing.assert_allclose(positions[0], [6.0, 2.5], atol=1e-9)
    np.testing.assert_allclose(velocities[0], [-1.0, 0.0], atol=1e-9)


def test_a_person_waits_rather_than_walk_into_the_robot():
    walking = Walker("p1", "head_on", np.array([[6.0, 2.0], [0.5, 2.0]]), speed=1.0)
    scene = open_scene([walking])
    result = drive(scene, lambda state, t, obs: np.zeros(2), max_time=8.0)
    # the robot stands at x = 1 m; the person stops about 0.68 m (radii + 0.25) before it
    assert result.collision is None and not result.reached
    assert walking.position(8.0)[0] == pytest.approx(1.0 + 0.68, abs=0.15)


def test_a_person_setting_off_beside_the_robot_waits_rather_than_walk_into_it():
    # standing 0.48 m from the robot's centre (0.05 m from touching), they set off across its
    # spot between two steps: the first step would take them 0.06 m, into the robot
    crossing = Walker("p1", "crossing", np.array([[1.0, 2.48], [1.0, 0.5]]), speed=1.2,
                      depart=0.95)
    scene = open_scene([crossing])
    result = drive(scene, lambda state, t, obs: np.zeros(2), max_time=3.0)
    assert result.collision is None
    assert crossing.position(3.0)[1] == pytest.approx(2.48)


def test_a_person_coming_round_a_corner_waits_while_the_robot_stands_where_they_come_in():
    # they would come in 0.35 m beside the robot (which stands at x = 1 m), at 1 s
    entering = Walker("p1", "overtaking", np.array([[1.0, 2.35], [1.0, 3.8]]), speed=0.2,
                      depart=1.0, enters=True)
    scene = open_scene([entering])
    seen = {}

    def stand_then_drive(state, t, obs):
        seen[round(t, 1)] = len(obs.people)
        return np.array([0.5 if t >= 3.0 else 0.0, 0.0])
    result = drive(scene, stand_then_drive, max_time=9.0)
    assert result.collision is None
    assert seen[2.9] == 0                    # round the corner while the robot stood there
    assert seen[8.9] == 1 and entering.position(8.9)[1] > 2.5      # came in after it left


def test_a_drive_ends_at_the_goal_or_at_what_it_hits():
    scene = open_scene([])
    reached = drive(scene, lambda state, t, obs: np.array([0.5, 0.0]))
    # 7.7 m to the goal region at most 0.5 m/s (the smooth speed limit gives a little less)
    assert reached.success and 7.7 / 0.5 <= reached.time <= 7.7 / 0.4
    scene = open_scene([], clutter=[(5.0, 2.0, 0.3)])
    hit = drive(scene, lambda state, t, obs: np.array([0.5, 0.0]))
    assert hit.collision == "clutter" and hit.states[-1][0] == pytest.approx(5 - 0.48, abs=0.06)


@pytest.mark.skipif(not os.path.isdir(MAPS), reason="the real floor maps (../shared/data/maps) are absent")
def test_scenes_on_a_real_floor_map():
    grid = load_map(os.path.join(MAPS, "levine_6th.yaml"))
    scene = make_scene(grid, 0, people=4)
    assert 10.0 <= path_length(scene.path) <= 60.0
    assert grid.is_free(scene.path[:, 0], scene.path[:, 1]).all()
    assert scene.collision(scene.start, 0.0) is None
