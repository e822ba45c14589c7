"""Person-like demonstrators (the benchmark's drivers): quantised stick, reaction delay, idle tail
at the goal, distinct styles that mostly reach the goal without touching the obstacle (judged by
the scenario's own geometry), and their demonstrations feed the learner and the clone."""
import numpy as np
import pytest

from lfd_controller.demonstrators import STYLES, PersonLikeDriver, dart_demos, person_demos, quantise
from lfd_controller.errors import LfdError
from lfd_controller.learning import person_features
from lfd_controller.rewards import LinearReward, reward_from_dict


def test_stick_positions_are_quantised():
    assert [quantise(v, 3) for v in (-1.0, -0.3, 0.2, 0.74, 0.76, 2.0)] == [-1.0, -0.5, 0.0, 0.5, 1.0, 1.0]
    assert quantise(0.3, 5) == 0.25
    with pytest.raises(LfdError, match="unknown driving style 'racer'"):
        PersonLikeDriver("racer")


@pytest.mark.parametrize("style", sorted(STYLES))
def test_each_style_drives_like_a_person_and_reaches_the_goal(style, static_scenario):
    starts = static_scenario.sample_starts(6, seed=21)
    driver = PersonLikeDriver(style, random_state=1)
    reached = 0
    for start in starts:
        demo = driver.demonstrate(static_scenario, start)
        states = demo.states
        times = demo.times()[1:]
        # the recorded states are the model's (no collision means centre distance >= clearance)
        np.testing.assert_allclose(demo.rollout(), states, atol=1e-12)
        assert not np.any(static_scenario.collides(states, times))
        # reacts late: the first `delay` commands are zero (nothing has reached the stick yet)
        assert np.all(demo.actions[:demo.meta["delay"]] == 0.0) and np.any(demo.actions[demo.meta["delay"]])
        if static_scenario.reached(states[-1]):
            reached += 1
            # sits still at the goal before the recording ends (let go of the stick)
            assert np.all(demo.actions[-3:] == 0.0)
        # few stick positions: forward commands cluster at the style's levels (hand noise aside)
        forward = demo.actions[demo.actions[:, 0] > 0, 0] / driver.mapping.scale_linear
        levels = np.arange(1, STYLES[style].levels) / (STYLES[style].levels - 1)
        nearest = np.min(np.abs(forward[:, None] - levels[None, :] * 0.95 - 0.05), axis=1)
        assert np.median(nearest) < 0.1
    assert reached >= 5, f"{style}: {reached} of 6 drives reached the goal"


def test_styles_differ_in_speed_and_temperament(static_scenario):
    starts = static_scenario.sample_starts(4, seed=22)
    speeds = {}
    for style in STYLES:
        demos = person_demos(static_scenario, style, starts, seed=3)
        speeds[style] = np.mean([np.mean(d.states[:, 3]) for d in demos])
    assert speeds["cautious"] < speeds["steady"] < speeds["sporty"]
    mixed = person_demos(static_scenario, "mixed", starts, seed=3)
    assert {d.meta["style"] for d in mixed} == set(STYLES)


def test_dart_drives_keep_the_persons_commands_and_the_perturbed_states(static_scenario):
    starts = static_scenario.sample_starts(2, seed=23)
    for demo in dart_demos(static_scenario, "steady", starts, seed=4, noise=(0.15, 0.5)):
        # the executed commands were perturbed, so the model's replay of the labels drifts away
        assert np.abs(demo.rollout()[:, :2] - demo.states[:, :2]).max() > 1e-3


def test_person_features_round_trip_through_reward_files():
    features = person_features()
    assert {"goal_progress", "obstacle_predicted", "speed_squared"} <= set(features.state_names)
    assert features.get_params()["proximity_widths"] == [0.5, 0.8]
    reward = LinearReward(np.arange(len(features.names)) - 3.0, features)
    again = reward_from_dict(reward.to_dict())
    assert again.features.names == features.names and again.weights.tolist() == reward.weights.tolist()


def test_smoothing_averages_the_stick_and_bad_settings_are_refused(static_scenario):
    from lfd_controller.cioc import LinearCIOC
    from lfd_controller.demos import Demonstration, smooth_commands
    from lfd_controller.errors import DemonstrationError, LearningError

    actions = np.array([[0.0, 0.0], [0.3, 0.9], [0.0, 0.0], [0.3, 0.0]])
    demo = Demonstration(static_scenario, np.array([-2.4, 0.0, 0.0, 0.0, 0.0]), actions)
    assert smooth_commands(demo, 1) is demo
    np.testing.assert_allclose(smooth_commands(demo, 3).actions[1], [0.1, 0.3])
    with pytest.raises(DemonstrationError, match="window"):
        smooth_commands(demo, 0)
    with pytest.raises(LearningError, match="weight signs"):
        LinearCIOC(person_features(), signs={"goal_distanse": -1})
