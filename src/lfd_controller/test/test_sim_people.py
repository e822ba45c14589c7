"""Simulated people (lfd_controller.sim): every family reaches the goal itself on the scenarios,
and each kind of per-person variation does what it says (speed, reaction delay, stick positions,
hand noise, side, clearance, overshoot), judged by the scenario's own geometry and the recorded
drives, never by the learner's features."""
from dataclasses import replace

import numpy as np
import pytest

from lfd_controller.errors import LfdError
from lfd_controller.sim import (
    FAMILIES,
    PERSON_MAPPING,
    Person,
    dart_demos,
    draw_person,
    drive_figures,
    make_person,
    person_demos,
    quantise,
    unseen_layouts,
)
from robot_sim.scenarios import load_scenario

# a plain person: mid speed, no delay, an analogue-like stick, no noise, moderate clearance
PLAIN = Person(speed=0.45, delay=0, levels=9, noise=0.0, side=1.0, clearance=0.2, overshoot=0.0,
               turn_gain=2.5, idle_steps=6)
AHEAD = np.array([-2.5, 0.0, 0.0, 0.0, 0.0])       # the static obstacle dead ahead on the way


@pytest.fixture(scope="module")
def scenarios():
    named = {n: load_scenario(n) for n in ("static_obstacle", "moving_obstacle", "oscillating_obstacle")}
    named.update({s.name: s for s in unseen_layouts()})
    return named


def test_stick_positions_and_bad_persons():
    assert [quantise(v, 3) for v in (-1.0, -0.3, 0.2, 0.74, 0.76, 2.0)] == [-1.0, -0.5, 0.0, 0.5, 1.0, 1.0]
    assert quantise(0.3, 5) == 0.25
    with pytest.raises(LfdError, match="unknown demonstrator family 'racer'"):
        make_person("racer")
    with pytest.raises(LfdError, match="preferred speed"):
        replace(PLAIN, speed=2.0)
    drawn = [draw_person(seed) for seed in range(60)]
    assert all(0.2 <= p.speed <= 0.6 and 0 <= p.delay <= 3 and 0.05 <= p.clearance <= 0.45 for p in drawn)
    assert {p.side for p in drawn} == {-1.0, 1.0} and {p.delay for p in drawn} == {0, 1, 2, 3}


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_each_family_reaches_the_goal_itself(family, scenarios):
    """A person of each family (with a delay, a quantised stick and hand noise) gets to the goal
    without touching the obstacle: every take on the static obstacle and the offset layout, and
    with retakes (as person_demos keeps good takes) past the moving obstacles. The sweeping
    obstacle, as fast as the robot, beats most people (the bench reports each person's own
    success there); the takes kept from it never touch it."""
    person = replace(PLAIN, delay=1, levels=5, noise=0.03)
    for name, scenario in scenarios.items():
        starts = scenario.sample_starts(3, seed=41)
        if name in ("static_obstacle", "layout_offset_goal"):
            driver = make_person(family, 1, person=person)
            results = [driver.success(scenario, s) for s in starts]
            assert all(r["success"] for r in results), (name, results)
            continue
        demos = person_demos(scenario, family, starts, seed=2, person=person)
        for demo in demos:
            times = demo.times()[1:]
            assert demo.meta["reached"] and not np.any(scenario.collides(demo.states, times))
            assert scenario.reached(demo.states).any()
        if name != "oscillating_obstacle":
            assert len(demos) >= 2, (name, len(demos))


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_speed_delay_and_stick_are_what_the_person_says(family, scenarios):
    # an open road: the obstacle far from the way (speed is judged where nothing slows the person)
    static = scenarios["static_obstacle"]
    scenario = replace(static, obstacle=replace(static.obstacle, x=0.6, y=1.6, radius=0.2))
    start = np.array([-2.6, -0.2, 0.0, 0.0, 0.0])
    cruise = {}
    for speed in (0.3, 0.55):
        driver = make_person(family, 3, person=replace(PLAIN, speed=speed))
        actions, states, reached, _, _ = driver.drive(scenario, start)
        assert reached
        # cruising: the upper quartile of the speed while driving (not accelerating or braking)
        cruise[speed] = float(np.percentile(states[:, 3], 75))
        assert abs(cruise[speed] - speed) < 0.15 * speed, (speed, cruise[speed])
    for delay in (0, 3):
        driver = make_person(family, 3, person=replace(PLAIN, delay=delay))
        actions = driver.drive(scenario, start)[0]
        moving = np.flatnonzero(np.any(actions != 0.0, axis=1))
        assert moving[0] == delay                   # the first decision reaches the stick late
    # few stick positions: without hand noise every command is one of `levels` positions
    driver = make_person(family, 3, person=replace(PLAIN, levels=4))
    actions = driver.drive(scenario, start)[0]
    fractions = np.abs(actions) / np.array([PERSON_MAPPING.scale_linear, PERSON_MAPPING.scale_angular])
    np.testing.assert_allclose(fractions * 3, np.round(fractions * 3), atol=1e-9)
    # hand noise of 0.05 moves the commands off those positions by about that much
    driver = make_person(family, 3, person=replace(PLAIN, levels=4, noise=0.05))
    actions = driver.drive(scenario, start)[0]
    linear = np.abs(actions[actions[:, 0] != 0, 0]) / PERSON_MAPPING.scale_linear
    off = linear - np.round(linear * 3) / 3
    assert 0.03 < np.std(off) < 0.08


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_side_clearance_and_overshoot_are_what_the_person_says(family, scenarios):
    scenario = scenarios["static_obstacle"]
    passing = {}
    for side in (1.0, -1.0):       # the obstacle dead ahead: the person's own side decides
        driver = make_person(family, 4, person=replace(PLAIN, side=side))
        _, states, reached, _, _ = driver.drive(scenario, AHEAD)
        assert reached
        near = np.abs(states[:, 0] - scenario.obstacle.x) < 0.1
        passing[side] = float(np.mean(states[near, 1]))
    assert passing[1.0] > 0.2 and passing[-1.0] < -0.2, passing
    start = scenario.sample_starts(1, seed=43)[0] * 0 + np.array([-2.5, 0.1, 0.0, 0.0, 0.0])
    closest = {}
    for clearance in (0.05, 0.4):
        driver = make_person(family, 4, person=replace(PLAIN, clearance=clearance))
        _, states, reached, collided, _ = driver.drive(scenario, start)
        assert reached and not collided
        closest[clearance] = drive_figures(scenario, np.vstack([start, states]), reached, collided)["closest"]
    assert closest[0.4] > closest[0.05] + 0.15, closest
    assert closest[0.4] > 0.3, closest
    past = {}
    for overshoot in (0.0, 0.3):
        driver = make_person(family, 4, person=replace(PLAIN, overshoot=overshoot, speed=0.5))
        _, states, reached, _, _ = driver.drive(scenario, np.array([-2.5, -0.8, 0.3, 0.0, 0.0]))
        assert reached and scenario.reached(states[-1])      # corrected: it ends in the goal
        approach = -np.array([-2.5, -0.8]) / np.hypot(2.5, 0.8)
        past[overshoot] = float(np.max(states[:, :2] @ approach))
    assert past[0.3] > 0.2 and past[0.3] > past[0.0] + 0.1, past


def test_demonstrations_record_the_person_and_dart_keeps_the_persons_commands(scenarios):
    scenario = scenarios["static_obstacle"]
    starts = scenario.sample_starts(2, seed=44)
    demos = person_demos(scenario, "potential", starts, seed=5)
    assert demos and all(d.source == "person:potential" and d.meta["family"] == "potential" for d in demos)
    assert {d.meta["speed"] for d in demos} == {round(make_person("potential", 5).person.speed, 4)}
    np.testing.assert_allclose(demos[0].rollout(), demos[0].states, atol=1e-12)
    for demo in dart_demos(scenario, "potential", starts, seed=6, noise=(0.15, 0.5)):
        # the executed commands were perturbed, so the model's replay of the labels drifts away
        assert np.abs(demo.rollout()[:, :2] - demo.states[:, :2]).max() > 1e-3
