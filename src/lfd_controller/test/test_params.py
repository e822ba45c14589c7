"""The nodes' parameter classes (no ROS master): defaults, checks, the core objects built from
them, the learn_reward command line and the bag folder under $ROS_HOME."""
from pathlib import Path

import pytest

from lfd_controller.errors import LfdError
from lfd_controller.learning import controller_settings, learn_and_save
from lfd_controller.params import (
    DemoRecorderParams,
    JoyTeleopParams,
    LearnRewardParams,
    RewardControllerParams,
    learn_reward_parser,
)
from lfd_controller.ros_recorder import resolve_bag_dir
from lfd_controller.sim import person_demos
from lfd_controller.teleop import JoyMapping
from robot_common.errors import ConfigError, ModelError
from robot_common.unicycle import UnicycleLimits


def test_teleop_defaults_are_the_core_mapping_and_bad_values_are_refused():
    assert JoyTeleopParams.from_mapping({}).mapping() == JoyMapping()
    config = JoyTeleopParams.from_mapping({"scale_linear": 1, "deadzone": 0.0, "recorder": "rec/"})
    assert config.mapping().scale_linear == 1.0 and config.recorder == "rec/"
    with pytest.raises(ConfigError, match="axis_linear"):
        JoyTeleopParams.from_mapping({"axis_linear": 1.5})
    with pytest.raises(ConfigError, match="unknown"):
        JoyTeleopParams.from_mapping({"scale_lienar": 0.4})
    with pytest.raises(LfdError, match="deadzone"):
        JoyTeleopParams.from_mapping({"deadzone": 1.5}).mapping()


def test_controller_config_builds_the_limits_and_the_planner_options():
    config = RewardControllerParams.from_mapping({"reward_file": "r.yaml", "v_max": 1})
    assert config.limits() == UnicycleLimits(v_max=1.0)
    assert config.controller_options() == {"horizon": 20, "plan_dt": 0.2, "terminal": 10.0,
                                           "max_iter": 15, "detour": 0.0, "spread_seeds": False,
                                           "discount": 1.0, "min_horizon": 0, "arrival": 0.0, "unstall": 0.0,
                                           "stall_plans": False, "goal_seed": 0.0}
    with pytest.raises(ConfigError, match="rate"):
        RewardControllerParams.from_mapping({"rate": 0.0})
    with pytest.raises(ModelError, match="w_max"):
        RewardControllerParams.from_mapping({"w_max": -1.0}).limits()


def test_recorder_bag_dir_defaults_under_ros_home(monkeypatch, tmp_path):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    assert resolve_bag_dir(DemoRecorderParams.from_mapping({}).bag_dir) == tmp_path / "lfd_demos"
    assert resolve_bag_dir("") is None
    assert resolve_bag_dir("~/bags") == Path.home() / "bags"
    with pytest.raises(ConfigError, match="min_steps"):
        DemoRecorderParams.from_mapping({"min_steps": "5"})


def test_learn_reward_command_line_takes_the_class_defaults():
    config = LearnRewardParams.from_args(["--output", "r.yaml", "--bags", "a", "b", "--db-url", ""])
    expected = dict(LearnRewardParams.defaults(), output="r.yaml", bags=["a", "b"])
    assert config.to_dict() == expected and config.trim == 10
    config = LearnRewardParams.from_args(["--output", "r.yaml", "--kind", "gp", "--store-db",
                                          "--trim-steps", "-1", "--seed", "3"])
    assert (config.kind, config.store_db, config.trim, config.seed) == ("gp", True, None, 3)
    with pytest.raises(SystemExit):
        learn_reward_parser().parse_args(["--kind", "quadratic", "--output", "r.yaml"])
    with pytest.raises(SystemExit):
        learn_reward_parser().parse_args([])          # --output is required
    with pytest.raises(ConfigError, match="output"):
        LearnRewardParams.from_mapping({})


def test_a_person_reward_carries_the_controller_settings_it_is_driven_with(tmp_path, static_scenario):
    demos = person_demos(static_scenario, "tangent", static_scenario.sample_starts(3, seed=31), seed=5)
    person, linear = tmp_path / "person.yaml", tmp_path / "linear.yaml"
    # the acceptance check is tested in test_acceptance.py; here only the saved settings matter
    learn_and_save(demos, kind="person", output=str(person), calibration={"rounds": 0})
    learn_and_save(demos, kind="linear", output=str(linear))
    config = RewardControllerParams.from_mapping({"reward_file": str(person)})
    driven = config.with_reward_settings(controller_settings(person))
    # the person driving settings documented in src/lfd_controller/README.md
    assert (driven.horizon, driven.plan_dt, driven.terminal, driven.detour, driven.spread_seeds,
            driven.discount, driven.min_horizon, driven.arrival, driven.unstall, driven.stall_plans,
            driven.goal_seed, driven.collision_margin) == (20, 0.4, 0.0, 0.8, True, 0.97, 8, 0.25,
                                                           1.5, True, 1.0, 0.1)
    assert driven.rate == config.rate and driven.max_iter == config.max_iter
    assert controller_settings(linear) == {}
    assert config.with_reward_settings(controller_settings(linear)) == config
    kept = RewardControllerParams.from_mapping({"reward_file": str(person), "reward_settings": False})
    assert kept.with_reward_settings(controller_settings(person)) == kept
    with pytest.raises(ConfigError, match="rate"):
        config.with_reward_settings({"rate": 50.0})
    with pytest.raises(ConfigError, match="detour"):
        config.with_reward_settings({"detour": -1.0})
    with pytest.raises(ConfigError, match="discount"):
        config.with_reward_settings({"discount": 1.5})
    with pytest.raises(ConfigError, match="goal_seed"):
        config.with_reward_settings({"goal_seed": 2.0})
    with pytest.raises(ConfigError, match="min_horizon"):
        config.with_reward_settings({"min_horizon": 21})     # above ~horizon (20)
    with pytest.raises(ConfigError, match="min_horizon"):
        RewardControllerParams.from_mapping({"min_horizon": 1})
    with pytest.raises(ConfigError, match="arrival"):
        config.with_reward_settings({"arrival": -0.25})
    with pytest.raises(ConfigError, match="unstall"):
        config.with_reward_settings({"unstall": 1.0, "detour": 0.0})
