"""The node's parameters (no ROS master): defaults, the local-zone spellings, refused values,
the generated YAML, and the one "not fitted" convention."""
from pathlib import Path

import pytest

import robot_common.errors
from robot_common.errors import ConfigError
from traffic_gp.baselines import BinnedMean
from traffic_gp.errors import NotFittedError, TrafficError
from traffic_gp.params import TrafficServerParams

CONFIG_YAML = Path(__file__).resolve().parents[1] / "config" / "traffic_gp.yaml"


def test_defaults_are_the_documented_ones():
    config = TrafficServerParams.from_mapping({})
    assert (config.map_yaml, config.cell_size, config.model_path) == ("", 0.5, "")
    assert config.utc_offset_hours is None and config.clock == "ros"
    assert (config.min_rows, config.initial_steps, config.wall_value) == (2000, 600, -1)
    assert config.model == {} and config.full_resolution and config.frame_id == "map"


@pytest.mark.parametrize("value, expected", [("", None), ("local", None), (None, None), (0, 0.0),
                                             (2, 2.0), (-3.5, -3.5), ("1.5", 1.5)])
def test_utc_offset_accepts_the_local_zone_spellings_and_numbers(value, expected):
    assert TrafficServerParams.from_mapping({"utc_offset_hours": value}).utc_offset_hours == expected


@pytest.mark.parametrize("params, match", [
    ({"clock": "wall"}, "clock"),
    ({"wall_value": 50}, "wall_value"),
    ({"utc_offset_hours": "Berlin"}, "utc_offset_hours"),
    ({"min_rows": "many"}, "min_rows"),
    ({"cel_size": 0.5}, "unknown parameter"),
])
def test_bad_parameters_are_refused_with_the_name(params, match):
    with pytest.raises(ConfigError, match=match):
        TrafficServerParams.from_mapping(params)


def test_the_config_file_is_generated_from_the_class():
    title = CONFIG_YAML.read_text().splitlines()[0][2:]
    assert CONFIG_YAML.read_text() == TrafficServerParams.render_yaml(title)


def test_errors_follow_the_workspace_convention():
    with pytest.raises(robot_common.errors.NotFittedError):
        BinnedMean(cells=None).predict(0.0, 0.0, 0.0)
    assert issubclass(NotFittedError, TrafficError)
    assert issubclass(TrafficError, robot_common.errors.WorkspaceError)
    import traffic_gp.errors
    assert not hasattr(traffic_gp.errors, "ConfigError")      # the workspace's one ConfigError


def test_the_people_counter_s_generated_yaml_holds_its_defaults_and_bad_values_are_refused():
    import yaml

    from traffic_gp.params import PeopleCounterParams

    path = CONFIG_YAML.with_name("people_counter.yaml")
    assert PeopleCounterParams.from_mapping(yaml.safe_load(path.read_text())) == PeopleCounterParams()
    config = PeopleCounterParams()
    assert (config.watch, config.max_range, config.min_detections) == (10.0, 8.0, 3)
    assert config.dwell_time == TrafficServerParams().dwell_time     # the server's exposure
    with pytest.raises(ConfigError, match="~max_range and ~dwell_time must be positive"):
        PeopleCounterParams.from_mapping({"max_range": 0.0})
    with pytest.raises(ConfigError, match="~min_detections must be >= 1"):
        PeopleCounterParams.from_mapping({"min_detections": 0})
