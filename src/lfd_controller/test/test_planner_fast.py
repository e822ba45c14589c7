"""The planner's fast paths against their slow references: the hand-written first-order features
against the jets, the unicycle adjoint against step_derivatives and finite differences; plus the
discount, the deadline, the spread seeds, the arrival look-ahead and the absorbing goal region of
the receding-horizon controller."""
import time

import numpy as np
import pytest

from lfd_controller.errors import LfdError
from lfd_controller.features import FeatureSet, Task
from lfd_controller.learning import load_reward, person_features, save_reward
from lfd_controller.planner import (
    ArrivalReward,
    CollisionBarrier,
    RecedingHorizonController,
    arrival_time_cost,
    goal_seed,
    optimise_commands,
    preferred_speed,
    trajectory_reward,
)
from lfd_controller.rewards import LinearReward, compose
from robot_common.unicycle import Unicycle
from robot_sim.scenarios import load_scenario

ALL_FEATURES = dict(forward_command=True, obstacle_facing=True, goal_slowing=True, goal_progress=True,
                    proximity_widths=(0.5, 0.8), predicted=1.0, state_effort=True)


class ReferenceUnicycle(Unicycle):
    """The same robot without `rollout_partials`, so trajectory_reward takes its generic path
    (rollout + step_derivatives + dense adjoint)."""

    rollout_partials = None


def random_trajectory(rng, count):
    states = np.column_stack([rng.uniform(-3, 1, count), rng.uniform(-2, 2, count),
                              rng.uniform(-3, 3, count), rng.uniform(-0.6, 0.6, count),
                              rng.uniform(-2, 2, count)])
    return states, rng.normal(size=(count, 2)), rng.uniform(0.0, 20.0, count)


@pytest.mark.parametrize("options", [{}, ALL_FEATURES, dict(goal_distance=False, goal_progress=True,
                                                                predicted=0.7, state_effort=True)])
@pytest.mark.parametrize("name", ["static_obstacle", "moving_obstacle", "oscillating_obstacle"])
def test_hand_written_first_order_features_match_the_jets(options, name):
    rng = np.random.default_rng(3)
    features = FeatureSet(**options)
    task = Task.from_scenario(load_scenario(name))
    states, actions, times = random_trajectory(rng, 25)
    weights = rng.normal(size=len(features.names))
    weights[1] = 0.0                                   # a zero weight is skipped, not mis-summed
    count = len(features.state_names)
    fv = features.evaluate(states, actions, times, task, order=1)
    reference = compose(fv, np.broadcast_to(weights[:count], fv.state.shape), None,
                        fv.state @ weights[:count], weights[count:], 1)
    value, rx, ru = features.weighted_first_order(states, actions, times, task, weights[:count],
                                                  weights[count:])
    np.testing.assert_allclose(value, reference.value, atol=1e-12)
    np.testing.assert_allclose(rx, reference.rx, atol=1e-12)
    np.testing.assert_allclose(ru, reference.ru, atol=1e-12)


def person_like_reward(rng):
    features = person_features()
    weights = -np.abs(rng.normal(size=len(features.names))) * 10.0
    weights[list(features.names).index("goal_progress")] = 80.0
    return LinearReward(weights, features)


@pytest.mark.parametrize("plan_dt", [0.1, 0.4])
def test_the_unicycle_adjoint_matches_the_generic_path_and_finite_differences(plan_dt):
    rng = np.random.default_rng(7)
    scenario = load_scenario("moving_obstacle")
    task = Task.from_scenario(scenario)
    reward = CollisionBarrier(person_like_reward(rng), scenario.clearance)
    start = np.array([-1.8, -0.9, 0.3, 0.2, 0.4])
    actions = rng.normal(size=(12, 2)) * [0.5, 2.0]
    for terminal, discount in ((0.0, 1.0), (3.0, 0.9)):
        fast = trajectory_reward(reward, Unicycle(plan_dt), task, start, 1.5, actions,
                                 terminal=terminal, discount=discount)
        slow = trajectory_reward(reward, ReferenceUnicycle(plan_dt), task, start, 1.5, actions,
                                 terminal=terminal, discount=discount)
        assert fast[0] == pytest.approx(slow[0], abs=1e-10)
        np.testing.assert_allclose(fast[1], slow[1], atol=1e-9)
        step, numeric = 1e-6, np.zeros_like(actions)
        for index in np.ndindex(actions.shape):
            up, down = actions.copy(), actions.copy()
            up[index] += step
            down[index] -= step
            numeric[index] = (trajectory_reward(reward, Unicycle(plan_dt), task, start, 1.5, up,
                                                gradient=False, terminal=terminal, discount=discount)[0]
                              - trajectory_reward(reward, Unicycle(plan_dt), task, start, 1.5, down,
                                                  gradient=False, terminal=terminal,
                                                  discount=discount)[0]) / (2 * step)
        np.testing.assert_allclose(fast[1], numeric, rtol=1e-5, atol=1e-4)


def test_the_discount_weighs_step_t_by_discount_to_the_t():
    rng = np.random.default_rng(11)
    scenario = load_scenario("static_obstacle")
    task, model = Task.from_scenario(scenario), Unicycle(0.4)
    reward = person_like_reward(rng)
    start, actions = np.array([-2.5, 0.3, 0.0, 0.0, 0.0]), np.tile([0.4, 0.1], (6, 1))
    states = model.rollout(start, actions)
    per_step = reward.derivatives(states, actions, 0.4 * np.arange(1, 7), task, order=0).value
    expected = sum(per_step[t] * 0.5 ** t for t in range(6))
    value, _ = trajectory_reward(reward, model, task, start, 0.0, actions, discount=0.5)
    assert value == pytest.approx(expected, rel=1e-12)


def test_a_passed_deadline_returns_the_initial_guess_and_no_deadline_improves_it():
    rng = np.random.default_rng(5)
    scenario = load_scenario("static_obstacle")
    task, model = Task.from_scenario(scenario), Unicycle(0.4)
    reward = person_like_reward(rng)
    start, initial = np.array([-2.5, 0.3, 0.0, 0.0, 0.0]), np.tile([0.2, 0.0], (20, 1))
    initial_value = trajectory_reward(reward, model, task, start, 0.0, initial, gradient=False)[0]
    plan, value = optimise_commands(reward, model, task, start, 0.0, initial, max_iter=15,
                                    deadline=time.perf_counter() - 1.0)
    np.testing.assert_array_equal(plan, initial)
    assert value == pytest.approx(initial_value)
    _, optimised = optimise_commands(reward, model, task, start, 0.0, initial, max_iter=15)
    assert optimised > initial_value + 1.0


def test_spread_seeds_try_one_alternative_per_call_in_turn():
    scenario = load_scenario("static_obstacle")
    task = Task.from_scenario(scenario)
    reward = person_like_reward(np.random.default_rng(2))
    controller = RecedingHorizonController(reward, scenario.model(), horizon=8, plan_dt=0.4,
                                           detour=0.8, spread_seeds=True)
    state = np.array([-2.5, 0.1, 0.0, 0.0, 0.0])
    every = controller._seeds(state, 0.0, task, None)
    assert len(every) == 5                              # three turning seeds + two detours
    for k in range(7):
        (one,) = controller._seeds(state, 0.0, task, k)
        np.testing.assert_array_equal(one, every[k % 5])
    with_goal = RecedingHorizonController(reward, scenario.model(), horizon=8, plan_dt=0.4,
                                          detour=0.8, spread_seeds=True, goal_seed=1.0)
    every = with_goal._seeds(state, 0.0, task, None)
    assert len(every) == 6                              # and the goal seed, last
    np.testing.assert_array_equal(every[5], goal_seed(with_goal.model, 8, state, 0.0, task, 1.0))
    np.testing.assert_array_equal(with_goal._seeds(state, 0.0, task, 11)[0], every[5])
    with pytest.raises(LfdError, match="goal_seed"):
        RecedingHorizonController(reward, scenario.model(), goal_seed=1.5)


def test_the_goal_seed_turns_toward_the_goal_and_drives_at_its_speed():
    scenario = load_scenario("oscillating_obstacle")
    task, model = Task.from_scenario(scenario), Unicycle(0.4, scenario.model().limits)
    start = np.array([-2.5, 0.0, 1.2, 0.0, 0.0])         # facing 69 deg left of the goal
    seed = goal_seed(model, 20, start, 0.0, task, 0.8)
    states = model.rollout(start, seed)
    assert seed[0, 1] < -1.0 and seed[0, 0] < 0.8 * model.limits.v_max   # turns right, slower
    heading = np.arctan2(-states[:, 1], -states[:, 0])                   # the goal is at (0, 0)
    away = np.hypot(*states[:, :2].T) > 0.5
    aligned = np.abs(np.arctan2(np.sin(heading - states[:, 2]), np.cos(heading - states[:, 2]))) < 0.05
    assert aligned[4:][away[4:]].all() and away[:8].all()
    assert np.allclose(seed[4:6, 0], 0.8 * model.limits.v_max, atol=0.01)
    assert np.hypot(*states[-1, :2]) < 0.2                               # it got there


def test_the_goal_seed_finds_the_way_past_a_sweeping_obstacle_before_it_comes_back():
    """The straight and turning guesses start along the robot's heading; from some starts they
    settle on waiting for the oscillating obstacle to sweep past and come back (about 7 s), where
    the plan started from heading for the goal slips past before it returns (under 5.5 s). Three
    such starts of twelve drawn; from the others both drive alike."""
    from lfd_controller.learning import person_controller, person_driving
    from robot_sim.scenarios import run_episode

    scenario = load_scenario("oscillating_obstacle")
    task = Task.from_scenario(scenario)
    features = person_features()
    weights = dict(goal_distance=-0.5, obstacle_proximity=-0.7, goal_progress=2.4,
                   speed_squared=-0.15, turn_squared=-0.05, speed_effort=-0.2, turn_effort=-0.3)
    reward = LinearReward([weights.get(name, 0.0) for name in features.names], features)
    times = {}
    for seed_speed in (0.0, 1.0):
        times[seed_speed] = []
        for start in np.asarray(scenario.sample_starts(12, seed=11))[[5, 7, 9]]:
            controller = person_controller(reward, scenario, budget=None,
                                           settings=dict(person_driving(0.1), goal_seed=seed_speed))
            result = run_episode(scenario, lambda x, t, c=controller: c.act(x, t, task), start)
            assert result.success and result.min_clearance > 0.0
            times[seed_speed].append(float(result.times[-1]))
    assert sum(t > 6.0 for t in times[0.0]) >= 2, times
    assert sum(t < 5.5 for t in times[1.0]) >= 2, times
    assert sum(times[1.0]) < 0.85 * sum(times[0.0]), times


def test_a_saved_person_reward_plans_identically_on_both_paths(tmp_path):
    """A reward file round trip does not change what the fast path computes."""
    rng = np.random.default_rng(9)
    reward = person_like_reward(rng)
    loaded = load_reward(save_reward(reward, tmp_path / "r.yaml"))
    scenario = load_scenario("oscillating_obstacle")
    task = Task.from_scenario(scenario)
    actions, start = rng.normal(size=(10, 2)) * 0.3, np.array([-2.0, 0.5, 0.2, 0.1, 0.0])
    a = trajectory_reward(reward, Unicycle(0.4), task, start, 2.0, actions)
    b = trajectory_reward(loaded, ReferenceUnicycle(0.4), task, start, 2.0, actions)
    assert a[0] == pytest.approx(b[0], abs=1e-10)
    np.testing.assert_allclose(a[1], b[1], atol=1e-9)


def test_preferred_speed_is_where_the_linear_and_squared_speed_terms_peak():
    features = person_features()
    weights = np.zeros(len(features.names))
    named = dict(goal_progress=60.0, speed_squared=-80.0, speed_effort=-20.0, turn_squared=-5.0)
    for name, value in named.items():
        weights[list(features.names).index(name)] = value
    reward = LinearReward(weights, features)
    # 60 v - 100 v^2 peaks at v = 60 / 200
    assert preferred_speed(reward, 0.6) == pytest.approx(0.3)
    assert preferred_speed(CollisionBarrier(reward, 0.45), 0.6) == pytest.approx(0.3)
    assert preferred_speed(reward, 0.25) == 0.25                     # never above the limit
    weights[list(features.names).index("goal_progress")] = 0.0
    assert preferred_speed(LinearReward(weights, features), 0.6) == 0.6     # no pull: the limit
    # no speed features at all: the limit
    assert preferred_speed(LinearReward(np.ones(len(FeatureSet().names)), FeatureSet()), 0.5) == 0.5
    with pytest.raises(LfdError, match="linear reward"):
        preferred_speed(object(), 0.6)


def test_the_arrival_look_ahead_ends_about_at_arrival_at_the_preferred_speed():
    features = person_features()
    weights = np.zeros(len(features.names))
    for name, value in dict(goal_progress=50.0, speed_squared=-100.0, goal_heading=1.0).items():
        weights[list(features.names).index(name)] = value
    reward = LinearReward(weights, features)       # preferred speed 50 / 200 = 0.25 m/s
    task = Task(np.array([0.0, 0.0]), lambda t: np.tile([10.0, 10.0], np.shape(t) + (1,)))
    controller = RecedingHorizonController(reward, Unicycle(0.1), horizon=20, plan_dt=0.4,
                                           min_horizon=8, max_iter=3, seed_iter=0)
    # 0.1 m per 0.4 s step: 3.05 m -> ceil(30.5) + 2 = 33, clipped to 20; 1.25 m -> 13 + 2 = 15;
    # 0.3 m -> 3 + 2 = 5, raised to 8
    for distance, steps in ((3.05, 20), (1.25, 15), (0.3, 8)):
        state = np.array([-distance, 0.0, 0.0, 0.2, 0.0])
        assert controller.planning_steps(state, task) == steps
        controller.act(state, 0.0, task)
        assert controller.steps_ == steps and controller.plan_.shape == (steps, 2)
    # the warm start follows the length: 8 -> 15 steps pads with the last command, 0.4 s later
    last = controller.plan_.copy()
    controller.steps_ = 15
    warm = controller._warm_start(0.4)
    np.testing.assert_allclose(warm[:7], last[1:8])
    np.testing.assert_allclose(warm[7:], np.tile(last[-1], (8, 1)))
    fixed = RecedingHorizonController(reward, Unicycle(0.1), horizon=20, plan_dt=0.4)
    assert fixed.planning_steps(np.array([-0.3, 0.0, 0.0, 0.0, 0.0]), task) == 20
    with pytest.raises(LfdError, match="min_horizon"):
        RecedingHorizonController(reward, Unicycle(0.1), horizon=20, min_horizon=25)
    with pytest.raises(LfdError, match="linear reward"):
        RecedingHorizonController(object(), Unicycle(0.1), min_horizon=8)


def far_obstacle(t):
    return np.tile([10.0, 10.0], np.shape(t) + (1,))


def test_the_arrival_reward_is_the_goals_rest_value_inside_the_region_and_the_reward_outside():
    features = FeatureSet()            # goal_distance softened by 0.2 m, squared commands
    weights = np.zeros(len(features.names))
    weights[list(features.names).index("goal_distance")] = -2.0
    weights[list(features.names).index("speed_effort")] = -3.0
    task = Task(np.array([1.0, 2.0]), far_obstacle)
    arrival = ArrivalReward(LinearReward(weights, features), 0.25, band=0.1)
    # goal distances 0.1 (inside the band: all the goal's value), 0.25 (the region's edge: half),
    # 0.27 (z = (0.30 - 0.27) / 0.1 = 0.3: 3 z^2 - 2 z^3 = 0.216), 0.5 (outside: the reward)
    distances = np.array([0.1, 0.25, 0.27, 0.5])
    states = np.column_stack([1.0 - distances, np.full(4, 2.0), np.full(4, 0.3), np.full(4, 0.2),
                              np.zeros(4)])
    actions = np.tile([0.4, 0.3], (4, 1))

    def own(d):             # -2 (sqrt(d^2 + 0.2^2) - 0.2) - 3 x 0.4^2; at rest at the goal: 0
        return -2.0 * (np.sqrt(d * d + 0.04) - 0.2) - 0.48
    expected = [0.0, 0.5 * own(0.25), (1.0 - 0.216) * own(0.27), own(0.5)]
    value = arrival.derivatives(states, actions, np.zeros(4), task, order=1).value
    np.testing.assert_allclose(value, expected, atol=1e-12)
    np.testing.assert_allclose(arrival.weight(distances)[0], [1.0, 0.5, 0.216, 0.0], atol=1e-12)
    # a time cost is paid by every step before arrival, not by the goal's value
    priced = ArrivalReward(arrival.reward, 0.25, band=0.1, time_cost=1.5)
    value = priced.derivatives(states, actions, np.zeros(4), task, order=1).value
    np.testing.assert_allclose(value, [0.0, 0.5 * (own(0.25) - 1.5), (1.0 - 0.216) * (own(0.27) - 1.5),
                                       own(0.5) - 1.5], atol=1e-12)
    with pytest.raises(LfdError, match="first derivatives"):
        arrival.derivatives(states, actions, np.zeros(4), task, order=2)
    with pytest.raises(LfdError, match="time cost"):
        ArrivalReward(arrival.reward, 0.25, time_cost=-1.0)
    with pytest.raises(LfdError, match="arrival radius"):
        ArrivalReward(arrival.reward, 0.25, band=0.6)
    with pytest.raises(LfdError, match="arrival radius"):
        RecedingHorizonController(arrival.reward, Unicycle(0.1), arrival=-0.25)


def test_the_arrival_time_cost_is_the_squared_speed_weight_times_the_preferred_speed_squared():
    features = person_features()
    weights = np.zeros(len(features.names))
    weights[list(features.names).index("goal_progress")] = 60.0
    weights[list(features.names).index("speed_squared")] = -100.0
    reward = LinearReward(weights, features)
    # v* = 60 / 200 = 0.3 m/s: 100 x 0.3^2 = 9; capped at v_max 0.25: 100 x 0.25^2 = 6.25
    assert arrival_time_cost(reward, 0.6) == pytest.approx(9.0)
    assert arrival_time_cost(CollisionBarrier(reward, 0.45), 0.25) == pytest.approx(6.25)
    weights[list(features.names).index("speed_squared")] = 0.0
    assert arrival_time_cost(LinearReward(weights, features), 0.6) == 0.0     # no speed penalty
    with pytest.raises(LfdError, match="linear reward"):
        arrival_time_cost(object(), 0.6)


def test_the_arrival_reward_gradient_matches_finite_differences_across_the_region_edge():
    rng = np.random.default_rng(11)
    scenario = load_scenario("static_obstacle")
    task = Task.from_scenario(scenario)
    reward = ArrivalReward(CollisionBarrier(person_like_reward(rng), scenario.clearance), 0.25,
                           time_cost=5.0)
    model = Unicycle(0.4, scenario.model().limits)
    start = np.array([0.6, 0.3, np.pi + 0.3, 0.2, 0.0])
    actions = np.column_stack([rng.uniform(0.05, 0.3, 8), rng.uniform(-0.3, 0.3, 8)])
    distances = np.hypot(*model.rollout(start, actions)[:, :2].T)
    assert distances.max() > 0.3 and 0.2 < distances[(distances < 0.3)].max()   # crosses the edge
    _, grad = trajectory_reward(reward, model, task, start, 0.0, actions, discount=0.97)
    step, numeric = 1e-6, np.zeros_like(actions)
    for index in np.ndindex(*actions.shape):
        bump = np.zeros_like(actions)
        bump[index] = step
        numeric[index] = (trajectory_reward(reward, model, task, start, 0.0, actions + bump,
                                            gradient=False, discount=0.97)[0]
                          - trajectory_reward(reward, model, task, start, 0.0, actions - bump,
                                              gradient=False, discount=0.97)[0]) / (2 * step)
    np.testing.assert_allclose(grad, numeric, atol=1e-5 * np.abs(numeric).max())


def test_an_absorbing_goal_arrives_where_effort_costs_make_the_plan_creep():
    # A sporty person reward (weights as learned from the sporty static demos, rounded): turning
    # is dear and the progress pull fades near the goal. 0.56 m before the goal, heading 32 deg
    # off it at 0.15 m/s, the straight line passes 0.30 m from the goal: a 0.25 m region needs a
    # small turn. Without an absorbing goal the plan creeps along (6.3 s to arrive, at 0.03 m/s);
    # with it (steps after arrival cost nothing, steps before it arrival_time_cost) the robot
    # turns in at speed.
    features = person_features()
    learned = dict(goal_distance=-8.6, obstacle_proximity=-3.9, goal_progress=70.0,
                   speed_squared=-103.0, speed_effort=-2.5, turn_effort=-134.0)
    reward = LinearReward(np.array([learned.get(n, 0.0) for n in features.names]), features)
    task = Task(np.array([0.0, 0.0]), far_obstacle)
    model = Unicycle(0.1)

    def arrival_time(arrival):
        controller = RecedingHorizonController(reward, model, horizon=20, plan_dt=0.4, terminal=0.0,
                                               detour=0.8, spread_seeds=True, discount=0.97,
                                               min_horizon=8, arrival=arrival)
        state = np.array([-0.56, 0.0, 0.56, 0.15, 0.0])
        for k in range(40):
            state = model.step(state, controller.act(state, 0.1 * k, task))
            if np.hypot(state[0], state[1]) < 0.25:
                return 0.1 * (k + 1)
        return None
    assert arrival_time(0.0) is None                # no arrival within 4 s: the creep
    arrived = arrival_time(0.25)
    assert arrived is not None and arrived < 3.0


def test_with_the_time_cost_the_robot_arrives_at_about_its_preferred_speed():
    # A cautious person reward (rounded learned weights; v* = 110 / (2 x 206.6) = 0.266 m/s),
    # facing the goal 1.5 m away at 0.27 m/s: the region's edge (0.25 m) is 1.25 m away, 4.7 s at
    # v*. Without an absorbing goal the progress sum is the same however slowly it is made and
    # the plan slows to 0.07 m/s (7.6 s); absorbing alone also drops the progress inside the
    # region and is slower still (9.3 s); with arrival_time_cost it arrives in about 5 s.
    features = person_features()
    learned = dict(goal_distance=-4.7, goal_progress=110.0, speed_squared=-193.0,
                   speed_effort=-13.6, turn_effort=-1.6, turn_squared=-11.7)
    reward = LinearReward(np.array([learned.get(n, 0.0) for n in features.names]), features)
    task = Task(np.array([0.0, 0.0]), far_obstacle)
    model = Unicycle(0.1)

    def arrival_time(arrival, absorbing_only=False):
        controller = RecedingHorizonController(reward, model, horizon=20, plan_dt=0.4, terminal=0.0,
                                               detour=0.8, spread_seeds=True, discount=0.97,
                                               min_horizon=8, arrival=arrival)
        if absorbing_only:
            controller.reward = ArrivalReward(reward, arrival)
        state = np.array([-1.5, 0.0, 0.0, 0.27, 0.0])
        for k in range(100):
            state = model.step(state, controller.act(state, 0.1 * k, task))
            if np.hypot(state[0], state[1]) < 0.25:
                return 0.1 * (k + 1)
        return np.inf
    assert arrival_time(0.25) <= 1.15 * 1.25 / 0.266            # within 15 % of 4.7 s
    assert arrival_time(0.0) > 7.0                              # the crawl
    assert arrival_time(0.25, absorbing_only=True) > 7.0


def test_unstall_takes_a_controller_that_wants_to_stand_still_past_the_obstacle(static_scenario):
    """A reward that only prices the commands keeps the robot where it is; with unstall the controller
    gives up waiting after 1.5 s and follows a detour past the obstacle (on the side the robot
    faces, here the left of its way: the obstacle is dead ahead)."""
    from lfd_controller.learning import person_controller, person_driving, person_features
    from lfd_controller.rewards import LinearReward

    features = person_features()
    reward = LinearReward([-1.0 if n in ("speed_effort", "turn_effort") else 0.0 for n in features.names],
                          features)
    task, model = Task.from_scenario(static_scenario), static_scenario.model()
    moved = {}
    for unstall in (0.0, 1.5):
        controller = person_controller(reward, static_scenario, budget=None,
                                       settings=dict(person_driving(0.1), unstall=unstall))
        state = np.array([-2.5, 0.0, 0.05, 0.0, 0.0])
        for k in range(30):                       # 3 s at 10 Hz
            state = model.step(state, controller.act(state, 0.1 * k, task))
        moved[unstall] = (state[:2] - [-2.5, 0.0], controller.escapes_)
    assert np.hypot(*moved[0.0][0]) < 0.02 and moved[0.0][1] == 0
    assert moved[1.5][1] == 1 and moved[1.5][0][0] > 0.1 and moved[1.5][0][1] > 0.02, moved


def test_unstall_lets_a_robot_wait_for_a_moving_obstacle_to_pass():
    """Waiting for a moving obstacle is what a person who yields does: a controller that stands
    still in front of one is not sent on a blind detour across its way (it cut in front of the
    obstacle, closer than the person ever came)."""
    from lfd_controller.learning import person_controller, person_driving, person_features
    from lfd_controller.rewards import LinearReward

    scenario = load_scenario("moving_obstacle")
    features = person_features()
    reward = LinearReward([-1.0 if n in ("speed_effort", "turn_effort") else 0.0 for n in features.names],
                          features)
    task, model = Task.from_scenario(scenario), scenario.model()
    controller = person_controller(reward, scenario, budget=None,
                                   settings=dict(person_driving(0.1), unstall=1.5))
    state = np.array([-2.5, 0.0, 0.05, 0.0, 0.0])
    for k in range(30):                           # 3 s at 10 Hz, the obstacle crossing ahead
        state = model.step(state, controller.act(state, 0.1 * k, task))
    assert controller.escapes_ == 0 and np.hypot(state[0] + 2.5, state[1]) < 0.02, state


def test_unstall_counts_a_plan_that_slows_to_a_stop_in_front_of_the_obstacle(static_scenario):
    """A robot still creeping (above STALL_SPEED) toward a stop in front of a static obstacle is
    stalling already: its plan ends at rest away from the goal. The rule counts from that plan, not
    from when the creep drops below STALL_SPEED (3 s later in a drive of a slow person's reward);
    a plan that keeps moving, or that ends at rest at the goal, is not a stall."""
    from lfd_controller.learning import person_driving
    from lfd_controller.planner import STALL_SPEED

    features = person_features()
    reward = LinearReward([-1.0 if n in ("speed_effort", "turn_effort") else 0.0 for n in features.names],
                          features)
    task, model = Task.from_scenario(static_scenario), static_scenario.model()

    class Creeping(RecedingHorizonController):
        """Plans to slow from the robot's speed to rest over the horizon; commands the plan's start."""

        def _act(self, state, t, task, started=None):
            self.plan_ = np.column_stack([np.linspace(state[3], 0.0, self.horizon), np.zeros(self.horizon)])
            self._plan_time = t
            return self.plan_[0].copy()

    settings = dict(person_driving(0.1), unstall=1.5)
    settings.pop("collision_margin")
    assert settings["stall_plans"]
    standing_only = Creeping(reward, static_scenario.model(), budget=None,
                             **dict(settings, stall_plans=False))
    controller = Creeping(reward, static_scenario.model(), budget=None, **settings)
    for creeping in (standing_only, controller):
        state = np.array([-2.5, 0.0, 0.0, 0.2, 0.0])
        for k in range(20):                        # 2 s at 10 Hz
            state = model.step(state, creeping.act(state, 0.1 * k, task))
        assert state[3] > STALL_SPEED, state       # still creeping: standing alone does not count
    assert standing_only.escapes_ == 0 and controller.escapes_ == 1
    moving = np.column_stack([np.full(controller.horizon, 0.3), np.zeros(controller.horizon)])
    controller.plan_ = moving
    assert not controller._plans_to_stop(np.array([-2.5, 0.0, 0.0, 0.3, 0.0]), task, 0.375)
    controller.plan_ = np.zeros((controller.horizon, 2))
    assert controller._plans_to_stop(np.array([-2.5, 0.0, 0.0, 0.0, 0.0]), task, 0.375)
    assert not controller._plans_to_stop(np.array([-0.1, 0.0, 0.0, 0.0, 0.0]), task, 0.375)
