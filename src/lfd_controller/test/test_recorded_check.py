"""The acceptance check of a hallway reward on recorded drives (lfd_controller.recorded_check):
a recorded-style drive down a corridor with someone walking the other way (made with robot_sim
here, in the test: the core never imports the simulator), a learned reward accepted, a reward
that cannot drive refused naming the drive, and the map built from the scans."""
import math

import numpy as np
import pytest

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError
from lfd_controller.hallway import calibrate_pace, fit_hallway_reward, hallway_scenario
from lfd_controller.hallway_recording import RecordedSensors, moving_speed, recorded_windows
from lfd_controller.learning import RewardNotAcceptedError
from lfd_controller.recorded_check import RecordedWorld, ReplayedPeople, check_recorded, recorded_map
from robot_common.maps import FREE, OCCUPIED, UNKNOWN, GridMap


def corridor_scene():
    """A 5 m drive down a corridor (free 0.1..6.9 x 0.1..2.5 m) with someone walking the other
    way (a robot_sim HallwayScene)."""
    from robot_sim.hallway import HallwayScene, Walker

    cells = np.full((26, 70), OCCUPIED, dtype=np.int8)
    cells[1:-1, 1:-1] = FREE
    path = np.column_stack([np.linspace(1.0, 6.0, 51), np.full(51, 1.3)])
    walker = Walker("p0", "head_on", np.array([[6.0, 0.55], [1.0, 0.55]]), speed=0.6)
    return HallwayScene(GridMap(cells, 0.1), path, np.array([1.0, 1.3, 0.0, 0.0, 0.0]), [walker])


def corridor_recording():
    """A simulated person's drive through corridor_scene as the recorder keeps it:
    (Demonstration, RecordedSensors)."""
    from lfd_controller.sim.hallway_people import HallwayDriver
    from robot_sim.hallway import drive

    scene = corridor_scene()
    driver, seen = HallwayDriver("sampling_mpc", 0).reset(scene), []

    def policy(state, t, observation):
        seen.append((t, observation))
        return driver(state, t, observation)
    result = drive(scene, policy)
    assert result.success
    demo = Demonstration(hallway_scenario(), result.states[0], result.actions, 0.0,
                         result.states[1:], "person")
    return demo, RecordedSensors(scene.path, [(t, o.angles, o.ranges) for t, o in seen],
                                 [(t, o.people, o.velocities) for t, o in seen])


@pytest.fixture(scope="module")
def learned():
    """(drive, the reward learned from it)."""
    demo, sensors = corridor_recording()
    reward, _ = fit_hallway_reward(recorded_windows(demo, sensors), 0)
    return (demo, sensors), calibrate_pace(reward, moving_speed([demo]))


def test_a_reward_learned_from_a_corridor_drive_is_accepted_on_that_recording(learned):
    drive, reward = learned
    checked = check_recorded(reward, [drive], names=["corridor.bag"])
    person, controller = checked.person[0], checked.controller[0]
    assert person["success"] and person["collision"] is None
    # the person passed the walker on the 2.4 m wide corridor: closer than 1.5 m, never touching
    assert 0.0 < person["closest"] < 1.5
    assert checked.margin >= 0.1
    assert controller["success"], checked.drive_lines()
    assert checked.accepted and checked.failing_drives() == [] and checked.failure_lines() == []
    assert checked.to_dict()["accepted"] is True


def test_a_reward_going_backwards_is_refused_and_the_refusal_names_the_drive(learned):
    drive, reward = learned
    names = np.array(reward.features.names)
    backwards = type(reward)(np.where(names == "path_progress", -1.0, 1.0) * reward.weights,
                             reward.features)
    checked = check_recorded(backwards, [drive], names=["corridor.bag"])
    assert not checked.accepted
    assert not checked.controller[0]["success"]
    assert checked.failing_drives() == ["corridor.bag"]
    message = str(RewardNotAcceptedError(checked))
    assert "NOT saved" in message and "corridor.bag" in message
    assert "--accept-mismatch" in message


def standing_recording(scans, people=(), goal=(3.0, 0.0)):
    """A robot standing at the origin facing +x for 1 s, with these scans and people reports,
    its path straight to `goal`."""
    steps = 10
    states = np.zeros((steps, 5))
    demo = Demonstration(hallway_scenario(), np.zeros(5), np.zeros((steps, 2)), 0.0, states,
                         "person")
    return demo, RecordedSensors(np.array([[0.0, 0.0], goal]), list(scans), list(people))


def wall_and_person_scan(t):
    """A 360-beam scan at time t from the origin: a wall along x = 2 m (|y| < 1 m), a person
    (radius 0.25 m) at (0, 1.5); no return elsewhere."""
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    ranges = np.full(360, np.inf)
    with np.errstate(divide="ignore"):
        to_wall = 2.0 / np.cos(angles)
    on_wall = (np.cos(angles) > 0) & (np.abs(to_wall * np.sin(angles)) < 1.0)
    ranges[on_wall] = to_wall[on_wall]
    # the person's near side: a beam at bearing b from the origin meets the disc at
    # d = 1.5 sin b - sqrt(0.25^2 - (1.5 cos b)^2) where |1.5 cos b| < 0.25
    offset = 1.5 * np.cos(angles)
    on_person = (np.sin(angles) > 0) & (np.abs(offset) < 0.25)
    ranges[on_person] = 1.5 * np.sin(angles[on_person]) - np.sqrt(0.25 ** 2 - offset[on_person] ** 2)
    return t, angles, ranges


def near(grid, x, y, half=0.06):
    """The values of the cells within `half` m of (x, y) (a return on a cell's edge may fall in
    either cell)."""
    rows, cols = grid.world_to_cell(np.array([x - half, x + half]), np.array([y - half, y + half]))
    return set(np.unique(grid.cells[rows[0]:rows[1] + 1, cols[0]:cols[1] + 1]).tolist())


def test_the_map_of_a_recording_keeps_walls_not_people_and_only_what_beams_saw_is_free():
    person_report = (0.0, np.array([[0.0, 1.5]]), np.zeros((1, 2)))
    demo, sensors = standing_recording([wall_and_person_scan(0.1 * k) for k in range(10)],
                                       [person_report])
    grid = recorded_map(demo, sensors)
    assert OCCUPIED in near(grid, 2.0, 0.0)             # the wall where the beams end
    assert OCCUPIED in near(grid, 2.0, 0.7)
    assert near(grid, 1.0, 0.0) == {FREE}               # beams passed on their way to the wall
    assert near(grid, 2.5, 0.0) == {UNKNOWN}            # behind the wall: never seen, not free
    assert OCCUPIED not in near(grid, 0.0, 1.25, 0.1)   # the tracked person's near side
    assert near(grid, 0.0, 1.0) == {FREE}               # in front of the person
    assert near(grid, 0.0, 1.75) == {UNKNOWN}           # behind the person: never seen
    assert near(grid, -1.0, 0.0, 0.03) == {FREE}        # no return: free as far as the beams go
    # untracked, the same person's returns are an obstacle
    demo, sensors = standing_recording([wall_and_person_scan(0.1 * k) for k in range(10)])
    assert OCCUPIED in near(recorded_map(demo, sensors), 0.0, 1.25, 0.1)


def test_touching_a_replayed_person_counts_only_when_the_robot_drives_into_them():
    open_floor = GridMap(np.full((40, 40), FREE, np.int8), 0.1, (-2.0, -2.0, 0.0))
    standing = ReplayedPeople([(0.0, np.array([[0.4, 0.0]]), np.zeros((1, 2)))])
    world = RecordedWorld(open_floor, standing)         # robot 0.18 m + person 0.25 m: 0.43 m
    # driving at 0.5 m/s: 0.05 m a step; at x = 0 the robot is 0.40 m from the person's centre
    # and was 0.45 m one step before - its own step brought it onto them
    assert world.contact(np.array([0.0, 0.0, 0.0, 0.5, 0.0]), 0.5) == "person"
    assert world.contact(np.array([-0.2, 0.0, 0.0, 0.5, 0.0]), 0.5) is None    # 0.6 m: not yet
    assert world.contact(np.array([0.0, 0.0, math.pi, 0.5, 0.0]), 0.5) is None  # backing away
    # someone walking at 1 m/s into a robot standing (or creeping) where the recorded one was not
    walking = ReplayedPeople([(0.0, np.array([[0.9, 0.0]]), np.array([[-1.0, 0.0]]))])
    world = RecordedWorld(open_floor, walking)
    assert world.contact(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), 0.5) is None
    assert world.contact(np.array([0.0, 0.0, 0.0, 0.1, 0.0]), 0.5) is None
    assert world.person_gap(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), 0.5) == pytest.approx(-0.03)


def test_a_wall_is_touched_when_an_occupied_cell_centre_is_within_the_robot_radius():
    cells = np.full((40, 40), FREE, np.int8)
    cells[:, 30] = OCCUPIED                             # x in [1.0, 1.1): centres at x = 1.05
    world = RecordedWorld(GridMap(cells, 0.1, (-2.0, -2.0, 0.0)), ReplayedPeople([]))
    assert world.wall_gap(np.array([0.85, 0.05, 0.0, 0.0, 0.0])) == pytest.approx(0.2)
    assert world.contact(np.array([0.85, 0.05, 0.0, 0.0, 0.0]), 0.0) is None
    assert world.contact(np.array([0.9, 0.05, 0.0, 0.0, 0.0]), 0.0) == "wall"      # 0.15 m


def test_recordings_where_the_person_never_arrived_check_nothing_and_are_refused(learned):
    _, reward = learned
    demo, sensors = standing_recording([wall_and_person_scan(0.1 * k) for k in range(10)],
                                       goal=(1.0, 0.0))     # 1 m on, in the open: never reached
    checked = check_recorded(reward, [(demo, sensors)], names=["standing.bag"])
    assert not checked.person[0]["success"]
    assert not checked.accepted
    assert "nothing to check the controller against" in str(RewardNotAcceptedError(checked))


def test_steps_before_the_recorders_first_scan_are_left_out_of_the_windows(learned):
    # the recorder connected to /scan three steps after the drive started (its subscriptions
    # connect one by one): the windows start at the first step with a scan
    (demo, sensors), _ = learned
    late = RecordedSensors(sensors.path, sensors.scans[3:], sensors.people)
    windows = recorded_windows(demo, late)
    assert np.allclose(windows[0].start, demo.states[2])        # the state at step 3
    assert np.allclose(windows[0].actions, demo.actions[3:3 + len(windows[0].actions)])
    assert len(windows[0].actions) == len(recorded_windows(demo, sensors)[0].actions)
    after = RecordedSensors(sensors.path, [(1000.0, *scan[1:]) for scan in sensors.scans[:2]])
    with pytest.raises(DemonstrationError, match="no laser scan within the drive"):
        recorded_windows(demo, after)


def test_scans_from_outside_the_drive_are_a_clear_error_naming_the_drive():
    demo, sensors = standing_recording([wall_and_person_scan(100.0)])
    with pytest.raises(DemonstrationError, match="late.bag: no laser scan within the drive"):
        check_recorded(None, [(demo, sensors)], names=["late.bag"])
