"""The building simulator's core: driving on commands, the command timeout, clutter the laser sees
and the robot hits, people walking rounds through the halls who wait for the robot."""
import math

import numpy as np
import pytest

from robot_sim.building import generate_building
from robot_sim.errors import SimError
from robot_sim.floor_sim import FloorSim, RoundPlanner, crowd_size, default_start, floor_walkers
from robot_sim.hallway import Walker
from robot_sim.people import PeopleSimulator

FORWARD = np.array([0.0])           # one laser beam straight ahead


@pytest.fixture(scope="module")
def building():
    return generate_building(0)


def test_the_robot_drives_as_commanded_and_stops_at_a_wall(building):
    # main hall of seed 0: x 0.2-25.2, y 5.2-8.2; the default start is (1.7, 6.7) facing east
    start = default_start(building.grid, building, 0)
    assert np.allclose(start, [1.7, 6.7, 0.0])
    sim = FloorSim(building.grid, [], start, dt=0.05)
    for _ in range(100):                     # 5 s at 0.4 m/s (1 m/s^2: 0.4 s to get going)
        sim.set_command(0.4, 0.0)
        sim.step()
    # the model's smooth speed limit at 0.6 m/s: 0.4 / (1 + (0.4 / 0.6)^4)^(1/4) = 0.3824 m/s
    assert sim.state[3] == pytest.approx(0.3824, abs=0.001)
    assert 1.7 + 0.3824 * 4.6 < sim.state[0] < 1.7 + 0.3824 * 5.0
    assert sim.state[1] == start[1] and sim.state[2] == 0.0
    sim.place([3.0, 6.7, math.pi / 2])       # facing the north wall 1.5 m away
    assert sim.status == "running"
    for _ in range(200):
        sim.set_command(0.4, 0.0)
        sim.step()
        if sim.hit:
            break
    assert sim.status == "collided with wall"
    # stopped where its edge (0.18 m) meets the wall at y = 8.2 (0.1 m cells), and stays there
    assert 8.2 - 0.18 - 0.1 < sim.state[1] < 8.2 - 0.18 + 0.1 and sim.state[3] == 0.0
    where = sim.state.copy()
    sim.set_command(0.4, 0.0)
    assert sim.step().tolist() == [0.0, 0.0] and (sim.state == where).all()


def test_a_silent_command_lapses_after_the_timeout(building):
    sim = FloorSim(building.grid, [], [3.0, 6.7, 0.0], dt=0.05, command_timeout=0.5)
    sim.set_command(0.3, 0.2)
    applied = [sim.step().tolist() for _ in range(20)]
    assert applied[:10] == [[0.3, 0.2]] * 10          # 0.5 s: ten steps of 0.05 s
    assert applied[11:] == [[0.0, 0.0]] * 9
    assert abs(sim.state[3]) < 0.01 and abs(sim.state[4]) < 0.01
    with pytest.raises(SimError, match="must be finite"):
        sim.set_command(float("nan"), 0.0)


def test_an_added_obstacle_is_seen_hit_and_cleared(building):
    sim = FloorSim(building.grid, [], [3.0, 6.7, 0.0], dt=0.05)
    assert sim.scan(FORWARD, 10.0)[0] == 10.0           # the hall runs on for 22 m
    assert sim.add_obstacle(6.0, 6.7, 0.3) == 1
    # the laser, 0.1 m ahead of the centre, meets the disc at 6.0 - 0.3 = 5.7
    assert sim.scan(FORWARD, 10.0)[0] == pytest.approx(5.7 - 3.1, abs=1e-9)
    for _ in range(400):
        sim.set_command(0.5, 0.0)
        sim.step()
        if sim.hit:
            break
    assert sim.status == "collided with clutter"
    # stopped within a step (0.025 m at 0.5 m/s) past where its edge meets the disc
    assert 5.7 - 0.18 < sim.state[0] < 5.7 - 0.18 + 0.026 and sim.state[3] == 0.0
    sim.place([3.0, 6.7, 0.0])
    assert sim.status == "running"
    assert sim.clear_obstacles() == 1 and sim.scan(FORWARD, 10.0)[0] == 10.0
    with pytest.raises(SimError, match="positive radius"):
        sim.add_obstacle(1.0, 1.0, 0.0)
    with pytest.raises(SimError, match=r"a pose is \[x, y, yaw\]"):
        sim.place([1.0, 2.0])


def test_driving_into_a_standing_person_is_a_collision(building):
    person = Walker("person0", "standing", np.array([[5.0, 6.7]]))
    sim = FloorSim(building.grid, [person], [3.0, 6.7, 0.0], dt=0.05)
    for _ in range(400):
        sim.set_command(0.5, 0.0)
        sim.step()
        if sim.hit:
            break
    # the robot's edge (0.18 m) meets the person's (0.25 m) at x = 5.0 - 0.43, within a step
    assert sim.status == "collided with person" and 4.57 < sim.state[0] < 4.57 + 0.026


def _hall_of(building, point):
    area = building.area_at(*point)
    return area is not None and area.kind == "hall"


def test_people_walk_rounds_through_the_halls_and_are_always_there(building):
    grid, start = building.grid, np.array([1.7, 6.7, 0.0])
    planner = RoundPlanner(grid, 5, building=building)
    sim = FloorSim(grid, floor_walkers(planner, 4, keep_clear=start[:2]), start, planner=planner)
    first = sim.truth()[1]
    assert len(first) == 4 and np.hypot(*(first - start[:2]).T).min() > 1.0
    seen, before, steps = [], first, []
    for step in range(1200):                 # a minute: every round (<= 2 x 30 m) ends at least once
        sim.step()
        now = sim.truth()[1]
        steps.append(np.hypot(*(now - before).T).max())
        before = now
        if step % 20 == 0:
            names, positions, velocities = sim.truth()
            assert names == ["person0", "person1", "person2", "person3"]
            assert all(_hall_of(building, p) for p in positions)
            assert np.hypot(*velocities.T).max() <= 1.3 + 1e-6
            seen.append(positions)
    travelled = np.abs(np.diff(np.array(seen), axis=0)).sum(axis=(0, 2))
    assert (travelled > 10.0).all()           # each walked well over 10 m in the minute
    assert sim.hit is None
    # nobody moves faster than walking, a new round included (rounds end where they begin)
    assert max(steps) <= 1.3 * sim.dt + 1e-6


def test_a_person_waits_for_a_standing_robot_then_turns_back(building):
    grid = building.grid
    walker = floor_walkers(RoundPlanner(grid, 2, building=building), 1)[0]
    # the robot stands on the walker's way, 3 m ahead of where it is now
    ahead = walker.route[np.argmin(np.abs(walker.arc() - (walker.walked(0.0) * walker.speed + 3)))]
    sim = FloorSim(grid, [walker], [ahead[0], ahead[1], 0.0])
    gaps, held = [], []
    for _ in range(300):                     # 15 s
        sim.step()
        gaps.append(np.hypot(*(sim.truth()[1][0] - ahead)))
        held.append(sim.scene.people[0].holding)
    assert sim.hit is None and min(gaps) > 0.18 + 0.25
    first, last = held.index(True), len(held) - 1 - held[::-1].index(True)
    # it stood close in front of the robot for 5 s (100 steps) then walked off the way it came
    assert gaps[first] < 1.0 and 95 <= last - first <= 101
    assert max(gaps[last:]) > gaps[last] + 1.0


def test_the_tracker_reports_people_in_sight_with_their_velocities(building):
    grid, start = building.grid, np.array([1.7, 6.7, 0.0])
    sim = FloorSim(grid, floor_walkers(RoundPlanner(grid, 1, building=building), 6), start)
    for _ in range(100):
        sim.step()
    names, positions, velocities = sim.tracked(8.0)
    truth = dict(zip(*sim.truth()[:2]))
    assert set(names) <= set(truth)
    for name, position, velocity in zip(names, positions, velocities):
        assert np.allclose(position, truth[name]) and np.hypot(*(position - sim.state[:2])) <= 8.0
        assert np.hypot(*velocity) <= 1.3 + 1e-6


def test_a_crowd_hour_gives_the_people_models_number_in_its_halls(building):
    model = PeopleSimulator.from_building(building, 0.5)
    # 75 m^2 of main hall at 0.15 people/m^2 on a weekday afternoon (Monday 14:00) and a quiet
    # back hall: about 11-12 plus 1; at 3 in the morning nearly nobody
    assert 10.0 < crowd_size(model, 14.0) < 20.0 and crowd_size(model, 3.0) < 1.0
    walkers = floor_walkers(RoundPlanner(building.grid, 0, crowd=(model, 14.0)), 8)
    assert len(walkers) == 8
    assert all(_hall_of(building, w.route[0]) for w in walkers)
    with pytest.raises(SimError, match="must be >= 0"):
        floor_walkers(RoundPlanner(building.grid, 0), -1)
