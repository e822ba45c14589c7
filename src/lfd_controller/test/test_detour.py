"""Detours round what the path's planner never saw: planned on the floor map and the scan, kept
clear of what the scan shows, rejoining the path beyond it; none through a blocked hall; and the
controller, held up in a cup of clutter on its path, drives round it to the goal."""
import math

import numpy as np

from lfd_controller.detour import plan_detour, plan_give_way, scan_window
from lfd_controller.give_way import people_holding, ways_on
from lfd_controller.hallway import HALLWAY_SAFETY, HallwayController
from lfd_controller.hallway_features import HallwayFeatures, PathFollower
from lfd_controller.rewards import LinearReward
from robot_common.maps import FREE, OCCUPIED, GridMap
from robot_common.unicycle import Unicycle
from robot_sim.hallway import HallwayScene, Walker, drive

ANGLES = np.linspace(-math.pi, math.pi, 72, endpoint=False)


def hall(clutter, width=4.0, length=10.0):
    """A hall `width` m wide (0.1 m cells), the path along its middle from x = 1 m, clutter
    (x, y, radius) that the map does not have."""
    cells = np.full((int(width * 10) + 2, int(length * 10) + 20), OCCUPIED, dtype=np.int8)
    cells[1:-1, 1:-1] = FREE
    middle = 0.1 + width / 2.0
    xs = np.linspace(1.0, 1.0 + length, int(length * 10) + 1)
    path = np.column_stack([xs, np.full(len(xs), middle)])
    return HallwayScene(GridMap(cells, 0.1), path, np.array([1.0, middle, 0.0, 0.0, 0.0]), [],
                        clutter=np.asarray(clutter, float).reshape(-1, 3))


def cup(x=5.0, middle=2.1):
    """Discs of 0.15 m in a cup open toward the robot, 1.2 m across, on the path at `x`."""
    bottom = [(x, middle + dy, 0.15) for dy in np.arange(-0.6, 0.61, 0.2)]
    sides = [(x - dx, middle + side, 0.15) for dx in (0.2, 0.4, 0.6) for side in (-0.6, 0.6)]
    return bottom + sides


def progress_reward(**weights):
    """A hallway reward for progress along the path (10) against squared speed (-10), plus
    `weights` by feature name; every other feature 0."""
    features = HallwayFeatures()
    named = dict.fromkeys(features.names, 0.0)
    named.update(path_progress=10.0, speed_squared=-10.0, **weights)
    return LinearReward([named[n] for n in features.names], features)


def seen_from(scene, pose):
    return (tuple(pose), ANGLES, scene.scan(np.asarray(pose, float), 0.0, ANGLES, 8.0))


def test_a_detour_keeps_clear_of_what_the_scan_shows_and_rejoins_the_path_beyond_it():
    scene = hall([(5.0, 2.1, 0.4)])
    follower = PathFollower(scene.path, lookahead=4.0)
    follower.update([4.0, 2.1])
    path = plan_detour(follower, [4.0, 2.1], [seen_from(scene, (4.0, 2.1, 0.0))],
                       clearance=0.28, grid=scene.grid).path
    dense = np.vstack([np.linspace(a, b, 20) for a, b in zip(path[:-1], path[1:])])
    assert np.hypot(*(dense - [5.0, 2.1]).T).min() >= 0.4 + 0.28 - 0.08   # a cell's slack
    assert np.allclose(path[-1], scene.goal)
    rejoined = dense[(np.abs(dense[:, 1] - 2.1) < 1e-6) & (dense[:, 0] > 4.05)]
    assert rejoined[:, 0].min() > 5.4


def test_no_detour_through_a_hall_blocked_from_wall_to_wall():
    scene = hall([(5.0, y, 0.3) for y in np.arange(0.2, 4.1, 0.4)])
    follower = PathFollower(scene.path, lookahead=4.0)
    follower.update([4.0, 2.1])
    seen = [seen_from(scene, (4.0, 2.1, 0.0))]
    assert plan_detour(follower, [4.0, 2.1], seen, clearance=0.28, grid=scene.grid) is None
    assert plan_detour(follower, [4.0, 2.1], seen, clearance=0.28) is None


def test_without_a_map_only_what_the_scan_has_seen_free_is_free():
    scene = hall([(5.0, 2.1, 0.4)])
    window = scan_window([seen_from(scene, (4.0, 2.1, 0.0))], centre=(4.0, 2.1), half_width=3.0)
    behind, beside, walls = (5.8, 2.1), (5.0, 3.2), (4.0, 4.3)
    assert window.is_free(*np.transpose([beside])).all()
    assert not window.is_free(*np.transpose([behind, walls])).any()


def test_the_controller_held_up_in_a_cup_of_clutter_drives_round_it_to_the_goal():
    reward = progress_reward(turn_squared=-1.0, speed_effort=-1.0, turn_effort=-1.0,
                             wall_proximity=-1.0)
    scene = hall(cup(), length=8.0)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None, grid=scene.grid,
                                   safety=dict(HALLWAY_SAFETY))

    def policy(state, t, seen):
        return controller.act(state, t, seen.angles, seen.ranges, seen.people, seen.velocities)
    result = drive(scene, policy, max_time=150.0)
    assert result.collision is None
    assert result.reached, controller.status_
    assert controller.detours_ >= 1


def first_cycle(scene, pose, *, people=np.zeros((0, 2)), grid=True, **safety):
    """A standing controller's first cycle at `pose` with the scan of `scene` (its clutter and
    walls) and tracked `people`; the controller."""
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings={"max_iter": 2}, grid=scene.grid if grid else None,
                                   safety=dict(HALLWAY_SAFETY, **safety))
    people = np.asarray(people, float).reshape(-1, 2)
    ranges = scene.scan(np.asarray(pose, float), 0.0, ANGLES, 8.0)
    if len(people):     # the scan sees them too
        from robot_sim.crowd import disc_ranges
        ranges = np.minimum(ranges, disc_ranges(pose[0], pose[1], pose[2] + ANGLES, people, 0.25))
    controller.act(np.array([*pose, 0.0, 0.0]), 0.0, ANGLES, ranges, people,
                   np.zeros_like(people))
    return controller


def test_something_the_map_lacks_on_the_path_ahead_is_detoured_round_at_once():
    scene = hall([(4.0, 2.1, 0.3)])         # a cart on the path, 1.7 m ahead of the robot
    controller = first_cycle(scene, (2.0, 2.1, 0.0))
    assert controller.detours_ == 1         # at its first cycle: nothing has held it up yet
    path = controller.follower.path
    dense = np.vstack([np.linspace(a, b, 20) for a, b in zip(path[:-1], path[1:])])
    assert np.hypot(*(dense - [4.0, 2.1]).T).min() >= 0.3 + 0.28 - 0.08   # a cell's slack
    assert np.allclose(path[-1], scene.goal)
    assert first_cycle(scene, (2.0, 2.1, 0.0), replan_ahead=0.0).detours_ == 0   # off
    assert first_cycle(scene, (2.0, 2.1, 0.0), grid=False).detours_ == 0   # no map: can't tell
    assert first_cycle(scene, (0.5, 2.1, 0.0)).detours_ == 0   # 3.2 m ahead: not yet


def test_walls_of_the_map_and_tracked_people_on_the_path_ahead_are_no_reason_to_re_plan():
    door = hall([])
    door.grid.cells[:19, 40] = OCCUPIED     # a wall across the hall at x = 4 m, a door 0.5 m
    door.grid.cells[24:, 40] = OCCUPIED     # wide round the path (y 1.9-2.4 m)
    assert door.grid.is_free(4.05, 2.1) and not door.grid.is_free(4.05, 1.85)
    tried = -math.inf       # when the controller last looked for a detour round what is ahead
    assert first_cycle(door, (2.0, 2.1, 0.0))._ahead_tried == tried
    assert first_cycle(hall([]), (2.0, 2.1, 0.0), people=[(3.5, 2.1)])._ahead_tried == tried
    # a narrower door frame where the map has none is something the map lacks
    frame = hall([(4.05, y, 0.05) for y in np.arange(0.2, 1.91, 0.1)]
                 + [(4.05, y, 0.05) for y in np.arange(2.3, 4.1, 0.1)])
    assert first_cycle(frame, (2.0, 2.1, 0.0))._ahead_tried == 0.0


def test_held_up_again_after_a_detour_it_backs_up_unless_something_is_behind():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    state = np.array([2.0, 2.1, 0.0, 0.0, 0.0])
    for behind, backs in ((5.0, True), (0.2, False)):
        ranges = np.full(36, 5.0)
        ranges[[17, 18, 19]] = 0.2          # straight ahead, inside 0.18 + 0.05 m
        ranges[0] = behind
        controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                       settings={"max_iter": 2}, safety=dict(HALLWAY_SAFETY),
                                       grid=scene.grid)
        commands = [controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
                    for t in np.arange(0.0, 10.0, 0.1)]     # held up at 4 s and again at 8 s
        assert (controller.detours_, controller.backups_) == (1, 1)
        assert any(c[0] < 0 for c in commands) == backs
        assert controller.status_.startswith("backing up") == backs


def test_on_a_new_path_it_first_turns_in_place_toward_a_waypoint_behind_it():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    for heading, turns in ((math.pi, True), (0.5, False)):     # the path runs along +x
        controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                       settings={"max_iter": 2}, grid=scene.grid,
                                       safety=dict(HALLWAY_SAFETY))
        state = np.array([2.0, 2.1, heading, 0.0, 0.0])
        command = controller.act(state, 0.0, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
        assert (controller.status_ == "turning to the path") == turns, controller.status_
        if turns:
            assert command[0] == 0.0 and abs(command[1]) == 1.0
        controller.act(np.array([2.0, 2.1, 0.0, 0.0, 0.0]), 0.1, angles, ranges,
                       np.zeros((0, 2)), np.zeros((0, 2)))
        assert controller.status_ == "following"       # facing the path: done turning


def test_after_a_recovery_it_turns_in_place_toward_a_waypoint_behind_it():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    clear = np.full(36, 5.0)
    ranges = clear.copy()
    ranges[[17, 18, 19]] = 0.2          # a wall 0.2 m in front of a robot facing away from the path
    ranges[[35, 0, 1]] = 0.2            # and something right behind: its reward's way is held
    for wait, turns in ((1.0, True), (0.0, False)):
        controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                       settings={"max_iter": 2}, grid=scene.grid,
                                       safety=dict(HALLWAY_SAFETY, replan_after=wait))
        controller.act(np.array([2.0, 2.1, 0.0, 0.0, 0.0]), 0.0, angles, clear,
                       np.zeros((0, 2)), np.zeros((0, 2)))     # started facing its path
        state = np.array([2.0, 2.1, math.pi, 0.0, 0.0])       # then turned round and held
        statuses = []
        for t in np.arange(0.1, 1.6, 0.1):
            command = controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
            statuses.append(controller.status_)
        assert ("turning to the path" in statuses) == turns, statuses
        if turns:
            assert command[0] == 0.0 and abs(command[1]) == 1.0


def test_a_re_planned_path_keeps_what_the_robot_saw_and_its_recovery_counts():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings={"max_iter": 2}, grid=scene.grid,
                                   safety=dict(HALLWAY_SAFETY))
    state = np.array([2.0, 2.1, 0.0, 0.0, 0.0])
    for t in np.arange(0.0, 2.0, 0.1):
        controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    controller.detours_, seen = 2, len(controller._scans)
    back = scene.path[::-1]
    controller.new_path(back[back[:, 0] <= 2.0])        # back the way it came
    assert seen >= 3 and len(controller._scans) == seen and controller.detours_ == 2
    controller.act(state, 2.0, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    assert controller.status_ == "turning to the path"


def test_re_plans_of_the_same_way_keep_the_clocks_a_held_robot_reports_blocked_and_retries():
    # move_base re-plans the same way every 0.5 s (each a little off the last) while the way
    # is held by a wall across the hall in front: the recoveries and the blocked report still
    # come; blocked, the robot stays stopped for blocked_after s, then a re-plan tries again
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    ranges[[34, 35, 0, 1, 2]] = 0.3                         # right in front, 0.3 m
    safety = dict(HALLWAY_SAFETY, replan_after=1.0, blocked_after=2.0, give_way=False)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings={"max_iter": 2}, grid=scene.grid, safety=safety)
    state = np.array([2.0, 2.1, 0.0, 0.0, 0.0])
    statuses, kept = [], []
    for k, t in enumerate(np.arange(0.0, 14.0, 0.1)):
        if k % 5 == 4:
            kept.append((t, controller.new_path(scene.path + [0.0, 0.1 * (-1) ** k])))
        controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
        statuses.append((round(t, 1), controller.status_))
    blocked = [t for t, status in statuses if status.startswith("blocked")]
    assert blocked, statuses
    assert all(same for t, same in kept if t < blocked[0] + 2.0), kept
    assert controller.backups_ + controller.detours_ >= 1
    first = blocked[0]
    held = [status for t, status in statuses if first <= t < first + 2.0]
    assert all(status.startswith("blocked") for status in held), held
    assert any(not status.startswith("blocked") for t, status in statuses if t > first + 2.6)


def test_a_detour_goes_on_through_re_plans_of_the_same_way_until_it_rejoins_the_path():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall(cup(), length=12.0)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings={"max_iter": 2}, grid=scene.grid,
                                   safety=dict(HALLWAY_SAFETY, replan_after=1.0, give_way=False))
    nobody = (np.zeros((0, 2)), np.zeros((0, 2)))
    state = np.array([4.0, 2.1, 0.0, 0.0, 0.0])                # in the cup's mouth, held
    for t in np.arange(0.0, 1.5, 0.1):
        controller.act(state, t, *seen_from(scene, state)[1:3], *nobody)
    assert controller.detours_ == 1
    detour = controller.follower.path
    replan = scene.path + [0.0, 0.1]                            # the same way, a cell over
    assert controller.new_path(replan)
    assert controller.follower.path is detour                   # still going round the cup
    for k, point in enumerate(detour[detour[:, 0] <= 10.0]):   # round it, back on the path
        state = np.array([point[0], point[1], 0.0, 0.3, 0.0])
        controller.act(state, 1.5 + 0.1 * k, *seen_from(scene, state)[1:3], *nobody)
    assert controller.new_path(replan)
    assert np.array_equal(controller.follower.path, replan)


def test_a_route_elsewhere_starts_the_clocks_again():
    reward = progress_reward(speed_effort=-1.0, turn_effort=-1.0)
    scene = hall([])
    angles = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    ranges = np.full(36, 5.0)
    ranges[[34, 35, 0, 1, 2]] = 0.3
    safety = dict(HALLWAY_SAFETY, replan_after=1.0, blocked_after=2.0, give_way=False)
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   settings={"max_iter": 2}, grid=scene.grid, safety=safety)
    state = np.array([2.0, 2.1, 0.0, 0.0, 0.0])
    for t in np.arange(0.0, 0.95, 0.1):
        controller.act(state, t, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    # round the far side of a pillar 1 m behind: away from the way on
    elsewhere = np.array([[2.0, 2.1], [1.0, 3.6], [0.5, 3.6], [0.5, 0.6], [11.0, 0.6]])
    assert not controller.new_path(elsewhere)
    controller.act(state, 1.0, angles, ranges, np.zeros((0, 2)), np.zeros((0, 2)))
    assert controller.status_ == "turning to the path" and controller.backups_ == 0


def test_along_a_detour_the_waypoint_never_skips_a_stretch_out_of_sight():
    # a U round something: the far leg is in sight across the gap, the bottom of the U is not
    path = np.array([[0.0, 0.0], [0.0, -1.0], [1.0, -1.0], [1.0, 0.0], [1.0, 3.0]])

    def visible(point):
        return not (point[1] < -0.5 and 0.2 < point[0] < 0.8)
    plain = PathFollower(path, lookahead=4.0).update([0.0, 0.0], visible)
    close = PathFollower(path, lookahead=4.0, closely=3.0).update([0.0, 0.0], visible)
    assert plain[0] == 1.0                              # across the gap: the detour's corner cut
    assert close[0] <= 0.2 + 1e-9 and close[1] <= -0.5  # stops where the U goes out of sight


def test_with_track_names_a_passer_by_does_not_make_a_standing_group_wait_for_the_robot():
    robot = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    still = np.zeros((2, 2))
    standing = np.array([[1.0, 0.3], [1.0, -0.3]])          # in front: a group, and one who came
    earlier = [(np.array([[1.0, 0.3], [1.0, 1.0], [3.0, -0.3]]),   # the group, a passer-by,
                np.array([[0.0, 0.0], [0.8, 0.0], [-0.8, 0.0]]),   # "came" still walking up
                ["group", "passer", "came"])]
    assert people_holding(robot, standing, still, earlier).tolist() == [True, False]
    named = people_holding(robot, standing, still, earlier, names=["group", "came"])
    assert named.tolist() == [False, True]
    untracked = people_holding(robot, standing, still, earlier, names=["", "came"])
    assert untracked.tolist() == [True, True]               # no name: the old rule


def test_giving_way_goes_aside_away_from_whoever_waits_and_never_toward_them():
    scene = hall([])
    follower = PathFollower(scene.path, lookahead=4.0)
    follower.update([4.0, 2.1])
    person = np.array([[4.6, 2.1]])
    spot_path = plan_give_way(follower, [4.0, 2.1], person, [seen_from(scene, (4.0, 2.1, 0.0))],
                              clearance=0.28, grid=scene.grid)
    assert spot_path is not None
    spot = spot_path[-1]
    assert spot[0] <= 4.0 + 1e-9                        # on the robot's far side from them
    assert abs(spot[1] - 2.1) >= 0.8 - 1e-9             # off the path they come along
    assert np.hypot(*(spot - person[0])) >= 1.0 - 1e-9
    dense = np.vstack([np.linspace(a, b, 20) for a, b in zip(spot_path[:-1], spot_path[1:])])
    assert np.hypot(*(dense - person[0]).T).min() >= 0.6 - 1e-9
    # in a hall too narrow to step aside in there is no such spot
    narrow = hall([], width=1.2)
    follower = PathFollower(narrow.path, lookahead=4.0)
    follower.update([4.0, 0.7])
    assert plan_give_way(follower, [4.0, 0.7], [[4.6, 0.7]],
                         [seen_from(narrow, (4.0, 0.7, 0.0))], clearance=0.28,
                         grid=narrow.grid) is None


def distance_to_ray(point, start, way):
    """How far `point` is from the ray from `start` along the unit vector `way`."""
    offset = np.asarray(point, float) - np.asarray(start, float)
    along = max(float(offset @ way), 0.0)
    return float(np.hypot(*(offset - along * np.asarray(way, float))))


def test_giving_way_keeps_off_where_the_waiting_person_walks_on():
    scene = hall([])
    follower = PathFollower(scene.path, lookahead=4.0)
    follower.update([4.0, 2.1])
    person = np.array([4.6, 1.6])           # in front, to the right: waits to walk through
    toward = (np.array([4.0, 2.1]) - person) / np.hypot(0.6, 0.5)
    seen = [seen_from(scene, (4.0, 2.1, 0.0))]
    spot = plan_give_way(follower, [4.0, 2.1], [person], seen, clearance=0.28,
                         grid=scene.grid)[-1]
    assert distance_to_ray(spot, person, toward) >= 1.0 - 0.05      # a cell's slack
    # the way their track was walking counts too
    walked = np.array([-0.8, 0.6])
    spot = plan_give_way(follower, [4.0, 2.1], [person], seen, clearance=0.28, ways=[walked],
                         grid=scene.grid)[-1]
    assert min(distance_to_ray(spot, person, toward),
               distance_to_ray(spot, person, walked)) >= 1.0 - 0.05


def test_the_way_a_tracked_person_was_walking_is_their_track_s_latest():
    earlier = [(np.array([[3.0, 0.0]]), np.array([[-0.8, 0.0]]), ["a"]),
               (np.array([[2.0, 0.5]]), np.array([[0.0, 0.6]]), ["a"]),      # turned
               (np.array([[2.0, 1.0]]), np.array([[0.0, 0.0]]), ["a"])]      # stopped
    ways = ways_on([[2.0, 1.0], [5.0, 5.0]], earlier, names=["a", "b"])
    assert np.allclose(ways[0], [0.0, 1.0]) and np.isnan(ways[1]).all()
    assert np.isnan(ways_on([[2.0, 1.0]], earlier)).all()                 # no names: unknown


def test_still_in_the_way_at_its_spot_the_robot_moves_on_to_another():
    scene = hall([])
    controller = HallwayController(progress_reward(), scene.path, Unicycle(0.1), budget=None,
                                   grid=scene.grid)
    model, state = Unicycle(0.1), np.array([4.0, 2.1, 0.0, 0.0, 0.0])
    person, still = np.array([6.0, 2.1]), np.zeros(2)
    statuses = []
    for step in range(300):
        t = 0.1 * step
        if controller.give_ways_ == 0:          # held up by someone who walks up and stops
            state = np.array([4.0, 2.1, 0.0, 0.0, 0.0])
            person = np.array([max(6.0 - 0.8 * t, 4.7), 2.1])
            velocity = np.array([-0.8, 0.0]) if person[0] > 4.7 else still
        elif statuses[-1] == "giving way: waiting for people to pass" and \
                statuses.count(statuses[-1]) == 1:  # at its spot, they walk up to it again
            toward = np.array([4.0, 2.1]) - state[:2]   # from where it was held up
            person, velocity = state[:2] + 0.7 * toward / np.hypot(*toward), still
        command = controller.act(state, t, ANGLES, scene.scan(state, t, ANGLES, 8.0), [person],
                                 [velocity], ["p"])
        statuses.append(controller.status_)
        if statuses[-2:] == ["giving way: waiting for people to pass",
                             "giving way: to a spot out of the way"]:
            break
        state = model.step(state, command)
    assert controller.give_ways_ == 1 and "giving way: waiting for people to pass" in statuses
    assert statuses[-1] == "giving way: to a spot out of the way"        # moved on


def mouth(length=9.0, wide=4.0, narrow=1.2, at=4.0):
    """A hall `wide` m wide up to x = `at`, then a corridor `narrow` m wide on its middle (0.1 m
    cells); the path along the middle from x = 1 m."""
    scene = hall([], width=wide, length=length)
    xs, ys = scene.grid.cell_to_world(*np.indices(scene.grid.cells.shape))
    middle = 0.1 + wide / 2.0
    scene.grid.cells[(xs > at) & (np.abs(ys - middle) > narrow / 2.0)] = OCCUPIED
    return scene


def meet_at_mouth(give_way: bool):
    """(reached, times it gave way, distances to the walker while giving way) of a drive
    into a corridor that a walker comes down head-on, meeting the robot at its mouth."""
    reward = progress_reward(turn_squared=-1.0, speed_effort=-1.0, turn_effort=-1.0,
                             wall_proximity=-1.0)
    scene = mouth()
    # robot_sim's walkers wait for a robot in their way
    scene.people = [Walker("head_on", "head_on", np.array([[9.5, 2.1], [0.5, 2.1]]), 1.0,
                           depart=4.0)]
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=None,
                                   grid=scene.grid, safety=dict(HALLWAY_SAFETY, give_way=give_way))
    gaps = []

    def policy(state, t, seen):        # with the tracker's names: the same walker walked up
        command = controller.act(state, t, seen.angles, seen.ranges, seen.people, seen.velocities,
                                 seen.names)
        if controller.status_.startswith("giving way") and len(seen.people):
            gaps.append(float(np.hypot(*(seen.people[0] - state[:2]))))
        return command
    result = drive(scene, policy, max_time=60.0)
    assert result.collision is None
    return result.reached, controller.give_ways_, gaps


def test_a_walker_waiting_for_it_at_a_corridor_mouth_is_given_way_to():
    reached, give_ways, gaps = meet_at_mouth(True)
    assert reached and give_ways >= 1
    assert min(gaps) >= gaps[0] - 0.1                  # away from them, never toward them
    assert not meet_at_mouth(False)[0]                  # the waiting game, without giving way


def test_where_the_full_room_is_not_there_it_gives_way_with_less():
    # before the mouth the hall is 2.4 m wide: no spot there 0.8 m off the path and 1 m off the
    # walker's way keeps 0.28 m from the walls (give_way.GIVE_WAY_ROOMS' first room)
    scene = mouth(wide=2.4)
    middle, held = scene.path[0, 1], np.array([3.6, scene.path[0, 1], 0.0, 0.0, 0.0])
    follower = PathFollower(scene.path, lookahead=4.0)
    follower.update(held[:2])
    assert plan_give_way(follower, held[:2], [[4.3, middle]], [seen_from(scene, held[:3])],
                         clearance=0.28, grid=scene.grid) is None
    controller = HallwayController(progress_reward(), scene.path, Unicycle(0.1), budget=None,
                                   grid=scene.grid)
    for step in range(200):             # held up by someone who walks up and stops
        t = 0.1 * step
        person = np.array([max(6.0 - 0.8 * t, 4.3), middle])
        velocity = np.array([-0.8, 0.0]) if person[0] > 4.3 else np.zeros(2)
        controller.act(held, t, ANGLES, scene.scan(held, t, ANGLES, 8.0), [person], [velocity],
                       ["p"])
        if controller.give_ways_:
            break
    assert controller.give_ways_ == 1
    spot = controller._giving_way.path[-1]
    assert spot[0] <= held[0] + 1e-9                                 # away from them
    assert abs(spot[1] - middle) >= 0.75 - 0.05                      # off their way, a cell's slack


def test_who_held_it_up_and_still_stands_there_holds_it_up_after_their_walk_is_forgotten():
    robot = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    standing, still = np.array([[0.8, 0.05], [0.8, -0.6]]), np.zeros((2, 2))
    assert people_holding(robot, standing, still, []).tolist() == [False, False]
    held = people_holding(robot, standing, still, [], held_by=[[0.85, 0.0]])
    assert held.tolist() == [True, False]               # the other stands elsewhere
    walking = np.array([[0.5, 0.0], [0.0, 0.0]])
    assert people_holding(robot, standing, walking, [], held_by=[[0.85, 0.0]]).tolist() == \
        [False, False]                                   # walking on: waits for nobody
