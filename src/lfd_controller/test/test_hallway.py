"""Following a path among people: the features' derivatives, the local waypoint, the safety stop
and the blocked report, and a reward learned from a simulated person's drives in a corridor
that drives a corridor with other people to the goal."""
import math

import numpy as np
import pytest

from lfd_controller.hallway import (
    HALLWAY_DRIVING,
    HALLWAY_SAFETY,
    HallwayBarrier,
    HallwayController,
    TaskBuilder,
    fit_hallway_reward,
    hallway_acceptance,
    hallway_windows,
)
from lfd_controller.hallway_features import (
    HallwayFeatures,
    HallwayTask,
    PathFollower,
    in_sight,
    scan_points,
)
from lfd_controller.rewards import LinearReward
from lfd_controller.sim.hallway_people import HallwayDriver, drive_figures, hallway_demonstration
from robot_common.maps import FREE, OCCUPIED, GridMap
from robot_common.unicycle import Unicycle
from robot_sim.hallway import HallwayScene, Walker, drive


def test_feature_derivatives_match_finite_differences():
    rng = np.random.default_rng(0)
    task = HallwayTask([3.0, 0.0], [10.0, 0.0], rng.normal(size=(5, 2)), rng.normal(size=(3, 2)),
                       rng.normal(size=(3, 2)), 0.5)
    features = HallwayFeatures()
    states, actions = rng.normal(size=(4, 5)), rng.normal(size=(4, 2))
    times = 0.5 + 0.4 * np.arange(4)
    values = features.evaluate(states, actions, times, task, order=2)
    eps = 1e-6
    for i in range(5):
        step = np.zeros(5)
        step[i] = eps
        up = features.evaluate(states + step, actions, times, task, order=2)
        down = features.evaluate(states - step, actions, times, task, order=2)
        np.testing.assert_allclose((up.state - down.state) / (2 * eps), values.state_jac[..., i],
                                   atol=1e-6)
        np.testing.assert_allclose((up.state_jac - down.state_jac) / (2 * eps),
                                   values.state_hess[..., i], atol=1e-5)


def test_the_planning_path_gives_the_reference_features_weighted_values_and_gradients():
    rng = np.random.default_rng(1)
    features = HallwayFeatures()
    task = HallwayTask([2.0, 1.0], [9.0, 0.0], rng.normal(size=(7, 2)), rng.normal(size=(4, 2)),
                       rng.normal(size=(4, 2)), 0.3)
    states, actions = rng.normal(size=(12, 5)), rng.normal(size=(12, 2))
    times = 0.3 + 0.4 * np.arange(12)
    weights = rng.normal(size=len(features.state_names))
    weights[[1, 5]] = 0.0           # features of weight 0 are skipped by the fast path
    control = rng.normal(size=2)
    slow = features.evaluate(states, actions, times, task, order=1)
    value, state_grad, action_grad = features.weighted_first_order(states, actions, times, task,
                                                                   weights, control)
    np.testing.assert_allclose(value, slow.state @ weights + slow.control @ control, atol=1e-12)
    np.testing.assert_allclose(state_grad, np.einsum("k,tka->ta", weights, slow.state_jac),
                               atol=1e-12)
    np.testing.assert_allclose(action_grad, np.einsum("c,tca->ta", control, slow.control_jac),
                               atol=1e-12)


def test_people_count_only_through_sums_so_any_number_works():
    features = HallwayFeatures()
    state = np.array([[0.0, 0.0, 0.0, 0.5, 0.0]])
    one = HallwayTask([3, 0], [9, 0], people=[[1.0, 0.0]], velocities=[[0.0, 0.0]])
    two = HallwayTask([3, 0], [9, 0], people=[[1.0, 0.0]] * 2, velocities=[[0.0, 0.0]] * 2)
    column = features.names.index("people_proximity")
    a = features.evaluate(state, np.zeros((1, 2)), [0.0], one, order=1).state[0, column]
    b = features.evaluate(state, np.zeros((1, 2)), [0.0], two, order=2).state[0, column]
    # exp(-1 / (2 * 0.5^2)) = exp(-2) per person at 1 m
    assert a == pytest.approx(math.exp(-2.0)) and b == pytest.approx(2 * math.exp(-2.0))


def test_the_waypoint_moves_along_the_path_and_waits_at_a_corner():
    path = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0]])
    follower = PathFollower(path, lookahead=2.0)
    np.testing.assert_allclose(follower.update([1.0, 0.1]), [3.0, 0.0])
    np.testing.assert_allclose(follower.update([4.0, 0.0]), [5.0, 1.0])
    follower = PathFollower(path, lookahead=2.0)
    # nothing round the corner is in sight: the waypoint stays on the first leg
    waypoint = follower.update([4.0, 0.0], visible=lambda point: point[1] < 0.1)
    assert waypoint[1] < 0.1 and waypoint[0] <= 5.0


def test_a_person_on_the_path_hides_it_but_does_not_pull_the_waypoint_in():
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    angles = np.linspace(-math.pi, math.pi, 72, endpoint=False)
    ranges = np.full(72, 9.0)
    ranges[np.abs(angles) < 0.2] = 1.25             # ahead: something's front at 1.25 m
    hidden = PathFollower(path, lookahead=4.0).update([0.0, 0.0], in_sight(
        (0.0, 0.0, 0.0), angles, ranges))
    assert hidden[0] == pytest.approx(0.75)     # untracked: the waypoint waits 0.3 m in front
    builder = TaskBuilder(path, lookahead=4.0)
    task = builder(np.zeros(5), 0.0, angles, ranges, [[1.5, 0.0]], [[0.0, 0.0]])
    np.testing.assert_allclose(task.waypoint, [4.0, 0.0])   # a tracked person: 4 m ahead


def test_the_controller_aims_through_the_goal_so_its_pull_does_not_fade_there():
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    angles = np.linspace(-math.pi, math.pi, 72, endpoint=False)
    ranges = np.full(72, 9.0)
    state = np.array([9.67, 0.0, math.pi, 0.0, 0.0])       # 0.33 m short, facing away
    plain = TaskBuilder(path, lookahead=4.0)(state, 0.0, angles, ranges, [], [])
    np.testing.assert_allclose(plain.waypoint, [10.0, 0.0])
    arriving = TaskBuilder(path, lookahead=4.0, through_goal=True)(state, 0.0, angles, ranges,
                                                                   [], [])
    np.testing.assert_allclose(arriving.waypoint, [13.67, 0.0])
    np.testing.assert_allclose(arriving.destination, [10.0, 0.0])
    ranges[np.abs(angles) < 0.2] = 0.2                     # the goal hidden: the plain waypoint
    hidden = TaskBuilder(path, lookahead=4.0, through_goal=True)(
        np.array([9.67, 0.0, 0.0, 0.0, 0.0]), 0.0, angles, ranges, [], [])
    assert hidden.waypoint[0] <= 10.0


def test_the_scan_gives_one_nearest_point_per_sector_and_leaves_people_out():
    angles = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    ranges = np.array([1.0, 9.0, 9.0, 9.0, 0.5, 0.6, 9.0, 9.0])   # 0.5 m ahead, 1 m behind
    points = scan_points((0.0, 0.0, 0.0), angles, ranges, sectors=4, reach=3.0)
    assert len(points) == 2 and points[:, 0].max() == pytest.approx(0.5)
    left = scan_points((0.0, 0.0, 0.0), angles, ranges, sectors=4, people=np.array([[0.5, 0.0]]))
    assert left[:, 0].max() == pytest.approx(0.6 * math.cos(math.pi / 4))


def corridor(people=(), length=8.0):
    """A 2.4 m wide corridor (0.1 m cells), the path along its middle from x = 1 m."""
    cells = np.full((26, int(length * 10) + 20), OCCUPIED, dtype=np.int8)
    cells[1:-1, 1:-1] = FREE
    xs = np.linspace(1.0, 1.0 + length, int(length * 10) + 1)
    path = np.column_stack([xs, np.full(len(xs), 1.3)])
    return HallwayScene(GridMap(cells, 0.1), path, np.array([1.0, 1.3, 0.0, 0.0, 0.0]),
                        list(people))


def straight_reward():
    features = HallwayFeatures()
    weights = dict.fromkeys(features.names, 0.0)
    weights.update(path_progress=10.0, speed_squared=-10.0, turn_squared=-1.0, speed_effort=-1.0,
                   turn_effort=-1.0, wall_proximity=-1.0, people_proximity=-5.0)
    return LinearReward([weights[name] for name in features.names], features)


def test_the_controller_stops_for_what_the_scan_shows_inside_its_margin_and_reports_blocked():
    controller = HallwayController(straight_reward(), corridor().path, Unicycle(0.1), budget=None,
                                   settings=dict(HALLWAY_DRIVING, max_iter=2, seed_iter=1))
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    ranges[[0, 18]] = 0.2               # behind and straight ahead, inside 0.18 + 0.05 m
    state = np.array([1.0, 1.3, 0.0, 0.0, 0.0])
    command = controller.act(state, 0.0, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    assert command[0] == 0.0 and controller.status_.startswith("stopped: scan 0.20 m")
    for t in np.arange(0.1, 21.0, 1.0):
        command = controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    assert command.tolist() == [0.0, 0.0] and controller.status_.startswith("blocked: held up")


def test_what_stands_close_behind_or_beside_does_not_stop_the_robot_driving_on():
    controller = HallwayController(straight_reward(), corridor().path, Unicycle(0.1), budget=None)
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    ranges[[0, 9, 27]] = 0.2            # behind, right beside and left beside: 0.2 m < 0.23 m
    state = np.array([1.0, 1.3, 0.0, 0.3, 0.0])
    command = controller.act(state, 0.0, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    assert command[0] > 0.1 and controller.status_ == "following"


def test_the_barrier_keeps_the_taught_margin_from_people_and_the_wall_margin_from_the_scan():
    reward = straight_reward()
    task = HallwayTask([5.0, 1.3], [9.0, 1.3], points=[[2.0, 1.6]], people=[[2.0, 0.7]],
                       velocities=[[0.0, 0.0]])
    barrier = HallwayBarrier(reward, robot_radius=0.18, person_radius=0.25, margin=0.25,
                             wall_margin=0.1)
    # 0.3 m from the scan point (beyond 0.18 + 0.1), 0.6 m from the person (inside 0.43 + 0.25)
    state = np.array([[2.0, 1.3, 0.0, 0.3, 0.0]])
    action, times = np.zeros((1, 2)), np.zeros(1)
    plain = reward.derivatives(state, action, times, task).value[0]
    person_only = 10.0 * np.max(np.abs(reward.weights)) * ((0.43 + 0.25 - 0.6) / 0.25) ** 2
    assert barrier.derivatives(state, action, times, task).value[0] == pytest.approx(
        plain - person_only)
    # the same taught margin for the scan too: the scan point counts
    same = HallwayBarrier(reward, robot_radius=0.18, person_radius=0.25, margin=0.25,
                          wall_margin=0.25)
    assert same.derivatives(state, action, times, task).value[0] < plain - person_only - 1.0


def test_a_controller_taught_a_wide_room_to_people_still_drives_through_a_narrow_door():
    # a 0.6 m door across the corridor: 0.3 m each side of the robot's centre, more than the
    # safety stop's 0.23 m but less than the robot's radius plus a taught margin of 0.25 m
    scene = corridor(length=7.0)
    scene.grid.cells[:, 40] = OCCUPIED
    scene.grid.cells[10:16, 40] = FREE
    controller = HallwayController(
        straight_reward(), scene.path, Unicycle(0.1), budget=None, grid=scene.grid,
        settings=dict(HALLWAY_DRIVING, max_iter=6),
        safety=dict(HALLWAY_SAFETY, barrier_margin=0.25))
    held = {}

    def every_third_step(state, t, seen):
        if int(round(t / 0.1)) % 3 == 0:
            held["command"] = controller.act(state, t, seen.angles, seen.ranges, seen.people,
                                             seen.velocities)
        return held["command"]
    assert drive_figures(drive(scene, every_third_step, max_time=60.0))["success"]


def test_the_acceptance_check_refuses_only_failing_where_the_person_succeeded():
    person = [{"success": True, "time": 30.0}] * 4 + [{"success": False, "time": float("nan")}]
    good = [{"success": True, "time": 33.0, "collision": None}] * 4 + \
        [{"success": False, "time": float("nan"), "collision": None}]
    assert hallway_acceptance(person, good)["accepted"]
    missing = [dict(good[0], success=False)] * 2 + good[2:]
    verdict = hallway_acceptance(person, missing)
    assert not verdict["accepted"] and "50%" in verdict["failures"][0]


def test_a_reward_learned_from_a_person_in_a_corridor_drives_another_corridor():
    # two drives of a person past someone walking the other way (6 m corridor), every other
    # window: enough for the signs of the pull and the people terms (cheap: ~1 s)
    walker = Walker("p0", "head_on", np.array([[6.0, 0.55], [1.0, 0.55]]), speed=0.6)
    demos = []
    for seed in range(2):
        result, tasks = hallway_demonstration(HallwayDriver("sampling_mpc", seed),
                                              corridor([walker], length=6.0))
        assert result.success
        demos += hallway_windows(result.states, result.actions, tasks)[::2]
    reward, _ = fit_hallway_reward(demos)
    named = dict(zip(reward.features.names, reward.weights))
    people = [named[name] for name in ("people_proximity", "people_room", "people_predicted")]
    assert named["path_progress"] > 0 and min(people) < 0
    # someone standing in the way: the controller goes round (the detour after standing still)
    scene = corridor([Walker("p1", "group", np.array([[3.5, 1.5]]))], length=5.0)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings=dict(HALLWAY_DRIVING, max_iter=6))
    held = {}

    def every_third_step(state, t, seen):          # re-plan at 3.3 Hz (cheap), hold between
        step = int(round(t / 0.1))
        if step % 3 == 0:
            held["command"] = controller.act(state, t, seen.angles, seen.ranges, seen.people,
                                             seen.velocities)
        return held["command"]
    result = drive(scene, every_third_step, max_time=60.0)
    figures = drive_figures(result)
    assert figures["success"] and figures["closest"] > 0.0
