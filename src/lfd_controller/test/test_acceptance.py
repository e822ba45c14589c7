"""The acceptance check of a person reward (acceptance.py): the controller's own drives from the
demonstrations' starts must match the demonstrations' mean speed, time to goal and closest
approach; a reward that crawls is refused (and said so), calibration brings its speed to the
person's, and learn_and_save does not save a refused reward. The controllers here run without a
cycle budget, so a busy machine changes their cost, not their drives."""
import numpy as np
import pytest
import yaml

from lfd_controller.acceptance import calibrate, compare, trajectory_statistics
from lfd_controller.learning import (
    RewardNotAcceptedError,
    learn_and_save,
    person_controller,
    person_driving,
    person_features,
)
from lfd_controller.rewards import LinearReward
from lfd_controller.sim import Person, person_demos

PERSON = Person(speed=0.45, delay=2, levels=4, noise=0.04, side=1.0, clearance=0.2, overshoot=0.0,
                turn_gain=2.5, idle_steps=6)
# progress pulls, but the squared-speed penalties balance it at 1.0 / (2 x 8) = 0.06 m/s: a crawl
CRAWL = {"goal_distance": -0.05, "goal_progress": 1.0, "obstacle_proximity": -1.0,
         "obstacle_predicted": -0.5, "speed_squared": -2.0, "speed_effort": -6.0, "turn_squared": -0.3,
         "turn_effort": -0.3}


def unbudgeted(reward, scenario, margin):
    return person_controller(reward, scenario, budget=None, settings=person_driving(margin))


@pytest.fixture(scope="module")
def demos(static_scenario):
    taken = person_demos(static_scenario, "tangent", static_scenario.sample_starts(2, seed=51), seed=7,
                         person=PERSON)
    assert len(taken) == 2
    return taken


def crawling_reward():
    features = person_features()
    return LinearReward([CRAWL.get(name, 0.0) for name in features.names], features)


def test_statistics_of_a_straight_drive(static_scenario):
    # 0.3 m/s straight at the goal from 1.2 m: arrives when within 0.25 m, after (1.2 - 0.25) / 0.3
    steps = np.arange(0, 40)
    trajectory = np.column_stack([-1.2 + 0.03 * steps, np.zeros(40), np.zeros(40), np.full(40, 0.3),
                                  np.zeros(40)])
    stats = trajectory_statistics(static_scenario, trajectory)
    assert stats["reached"] and stats["time"] == pytest.approx(3.2, abs=0.11)
    assert stats["mean_speed"] == pytest.approx(0.3, rel=0.02)
    # it starts on the obstacle's centre: closest approach is minus the touching distance
    assert stats["closest"] == pytest.approx(-static_scenario.clearance)
    matched = compare({"mean_speed": 0.3, "time": 3.2, "closest": 0.2, "reached": 1.0},
                      {"mean_speed": 0.25, "time": 4.1, "closest": 0.32, "reached": 1.0})
    assert matched == {"mean_speed": True, "time": False, "closest": False, "reached": True}


def test_a_reward_that_crawls_is_refused_and_calibration_brings_it_to_the_persons_pace(demos):
    crawl = crawling_reward()
    # replanning every 0.4 s (one planning step) keeps the test short
    _, refused = calibrate(crawl, demos, unbudgeted, rounds=1, replan_every=4)
    assert not refused.accepted and not refused.matched["mean_speed"]
    assert refused.driven["mean_speed"] < 0.8 * refused.demonstrated["mean_speed"]
    text = refused.describe()
    assert "NOT matched" in text and "mean speed" in text.split("NOT matched")[1]
    calibrated, report = calibrate(crawl, demos, unbudgeted, rounds=4, replan_every=4)
    assert report.matched["mean_speed"] and report.matched["time"], report.describe()
    assert report.driven["mean_speed"] > 1.3 * refused.driven["mean_speed"]
    # only the speed penalties were rescaled; the pull toward the goal is the learned one
    names = crawl.features.names
    assert calibrated.weights[names.index("goal_progress")] == crawl.weights[names.index("goal_progress")]
    assert calibrated.weights[names.index("speed_effort")] > crawl.weights[names.index("speed_effort")]


def test_learn_and_save_does_not_save_a_refused_reward(demos, tmp_path):
    output = tmp_path / "reward.yaml"
    # a demand no controller meets (the speed exactly the person's): refused, nothing written
    strict = {"rounds": 1, "max_drives": 1, "speed_tolerance": 0.0}
    with pytest.raises(RewardNotAcceptedError, match="NOT saved.*NOT matched: mean speed"):
        learn_and_save(demos, kind="person", output=str(output), calibration=strict)
    assert not output.exists()
    summary = learn_and_save(demos, kind="person", output=str(output), calibration=strict,
                             accept_mismatch=True)
    assert "NOT accepted" in summary
    saved = yaml.safe_load(output.read_text())["info"]
    assert saved["acceptance"]["accepted"] is False and saved["acceptance"]["drives"] == 1
