"""Scenarios: YAML loading, time-indexed obstacles, random starts, collisions and bad files."""
import numpy as np
import pytest

from robot_common.errors import TaskError
from robot_common.tasks import scenario_from_yaml
from robot_sim.scenarios import load_scenario, run_episode, scenarios_dir


@pytest.mark.parametrize("name", ["static_obstacle", "moving_obstacle", "oscillating_obstacle"])
def test_shipped_scenarios_load_and_round_trip(name):
    scenario = load_scenario(name)
    assert scenario.name == name
    again = scenario_from_yaml(scenario.to_yaml())
    assert again.to_dict() == scenario.to_dict()
    np.testing.assert_allclose(again.obstacle.position([0.0, 3.0]), scenario.obstacle.position([0.0, 3.0]))


def test_moving_obstacles_are_indexed_by_time():
    linear = load_scenario("moving_obstacle").obstacle
    np.testing.assert_allclose(linear.position(4.0), [-1.3, -1.2 + 4.0 * 0.25])
    np.testing.assert_allclose(linear.velocity_at(1.0), [0.0, 0.25])
    swing = load_scenario("oscillating_obstacle").obstacle
    np.testing.assert_allclose(swing.position([0.0, 2.0, 4.0]), [[-1.2, 0.0], [-1.2, 0.8], [-1.2, 0.0]],
                               atol=1e-12)
    # velocity is the derivative of position
    eps = 1e-6
    numeric = (swing.position(1.3 + eps) - swing.position(1.3 - eps)) / (2 * eps)
    np.testing.assert_allclose(swing.velocity_at(1.3), numeric, atol=1e-6)
    assert load_scenario("static_obstacle").obstacle.position(7.0).tolist() == [-1.2, 0.0]


def test_random_starts_are_reproducible_clear_and_inside_ranges():
    scenario = load_scenario("static_obstacle")
    starts = scenario.sample_starts(200, seed=3)
    assert np.array_equal(np.array(starts), np.array(scenario.sample_starts(200, seed=3)))
    starts = np.array(starts)
    assert np.all((starts[:, 0] >= -2.7) & (starts[:, 0] <= -2.2))
    assert np.all(scenario.obstacle_distance(starts, 0.0) > scenario.clearance + 0.3)
    bearing = np.arctan2(-starts[:, 1], -starts[:, 0])
    offset = np.angle(np.exp(1j * (starts[:, 2] - bearing)))
    assert np.all(np.abs(offset) <= 0.6 + 1e-9) and np.all(starts[:, 3:] == 0)


def test_collisions_with_the_obstacle_and_the_arena_walls():
    scenario = load_scenario("moving_obstacle")
    at_obstacle_t4 = scenario.obstacle.position(4.0)
    assert scenario.collides(at_obstacle_t4, 4.0)
    assert not scenario.collides(at_obstacle_t4, 0.0)          # it was elsewhere at t = 0
    touching = at_obstacle_t4 + [scenario.clearance - 0.01, 0.0]
    clear = at_obstacle_t4 + [scenario.clearance + 0.01, 0.0]
    assert scenario.collides(touching, 4.0) and not scenario.collides(clear, 4.0)
    assert scenario.collides([0.95, 0.0], 0.0)                  # the wall at x = 1.0 (radius 0.18)
    assert scenario.reached([0.1, 0.1]) and not scenario.reached([0.3, 0.0])


def test_episode_stops_at_collision_and_at_the_goal():
    scenario = load_scenario("static_obstacle")
    start = np.array([-2.2, 0.0, 0.0, 0.0, 0.0])
    crash = run_episode(scenario, lambda state, t: np.array([0.5, 0.0]), start)
    assert crash.collided and not crash.reached and crash.min_clearance < 0
    assert scenario.obstacle_distance(crash.states[-1], crash.times[-1]) < scenario.clearance
    near = np.array([-0.6, 0.0, 0.0, 0.0, 0.0])
    arrive = run_episode(scenario, lambda state, t: np.array([0.4, 0.0]), near)
    assert arrive.reached and arrive.success and arrive.times[-1] < 3.0


@pytest.mark.parametrize("text, message", [
    ("goal: [1, 2]", "malformed 'goal'"),
    ("goal: {x: 0, y: 0}\nobstacle: {y: 0}", "missing 'x'"),
    ("goal: {x: 0, y: 0}\nobstacle: {x: 0, y: 1, radius: -1}", "radius must be positive"),
    ("goal: {x: 0, y: 0}\nobstacle: {x: 0, y: 1, motion: {kind: teleport}}", "motion kind"),
    ("goal: {x: zero, y: 0}\nobstacle: {x: 0, y: 1}", "'x' must be a number"),
    ("goal: {x: 0, y: 0}\nobstacle: {x: 0, y: 1}\nbounds: [1, 1, 0, 0]", "bounds"),
    ("goal: {x: 0, y: 0}\nobstacle: {x: 0, y: 1}\nstart: {x: [1]}", "start x"),
    ("[unclosed", "not valid YAML"),
])
def test_bad_scenarios_get_clear_errors(text, message):
    with pytest.raises(TaskError, match=message):
        scenario_from_yaml(text)


def test_missing_scenario_file_and_impossible_starts():
    with pytest.raises(TaskError, match="cannot read scenario file"):
        load_scenario("no_such_scenario")
    assert (scenarios_dir() / "static_obstacle.yaml").is_file()
    blocked = scenario_from_yaml("goal: {x: 0, y: 0}\nobstacle: {x: -2.45, y: 0, radius: 1.5}")
    with pytest.raises(TaskError, match="no start clear"):
        blocked.sample_start(0)
