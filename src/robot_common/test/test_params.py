"""The node-parameter convention: typed checks, unknown keys, defaults once, generated YAML."""
from dataclasses import dataclass
from typing import Optional

import pytest
import yaml

from robot_common.config_files import generated_files, stale_files
from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param


@dataclass
class ExampleConfig(NodeConfig):
    """Parameters of a made-up node."""

    rate: float = param(10.0, "cycles per second", minimum=0.0)
    steps: int = param(20, "planning steps")
    frame: str = param("odom", "the planning frame")
    mode: str = param("auto", "how to choose", choices=("auto", "fast", "exact"))
    enabled: bool = param(True, "start enabled")
    offset: Optional[float] = param(None, "UTC offset in hours; null: local zone")
    model: dict = param({"kernel": "rbf"}, "estimator keyword arguments")

    def check(self) -> None:
        if self.frame == "map" and self.mode == "fast":
            raise ConfigError("fast mode cannot plan in the map frame")


def test_defaults_fill_missing_keys_and_values_are_converted_only_int_to_float():
    config = ExampleConfig.from_mapping({"rate": 5, "steps": 3, "offset": -5})
    assert config.rate == 5.0 and isinstance(config.rate, float)
    assert config.steps == 3 and config.frame == "odom" and config.enabled is True
    assert config.offset == -5.0 and config.model == {"kernel": "rbf"}
    assert ExampleConfig.from_mapping({}).offset is None


@pytest.mark.parametrize("params, message", [
    ({"rate": "fast"}, r"~rate must be a float, got 'fast'"),
    ({"steps": 2.5}, r"~steps must be a int, got 2.5"),
    ({"enabled": 1}, r"~enabled must be a bool, got 1"),
    ({"rate": -1.0}, r"~rate must be >= 0.0, got -1.0"),
    ({"mode": "slow"}, r"~mode must be one of \['auto', 'fast', 'exact'\], got 'slow'"),
    ({"model": [1]}, r"~model must be a dict"),
    ({"rat": 1.0}, r"unknown parameter\(s\) ~rat"),
    ({"frame": "map", "mode": "fast"}, r"fast mode cannot plan in the map frame"),
])
def test_bad_values_are_refused_with_the_value_named(params, message):
    with pytest.raises(ConfigError, match=message):
        ExampleConfig.from_mapping(params)


def test_mutable_defaults_are_not_shared_between_instances():
    first = ExampleConfig.from_mapping({})
    first.model["kernel"] = "changed"
    assert ExampleConfig.from_mapping({}).model == {"kernel": "rbf"}


def test_rendered_yaml_loads_back_to_the_defaults_with_each_description():
    text = ExampleConfig.render_yaml("Parameters of the example node")
    assert yaml.safe_load(text) == {"rate": 10.0, "steps": 20, "frame": "odom", "mode": "auto",
                                    "enabled": True, "offset": None, "model": {"kernel": "rbf"}}
    assert "# cycles per second\nrate: 10.0\n" in text
    assert text.splitlines()[1].startswith(f"# Generated from {__name__}:ExampleConfig;")


def test_a_parameter_needs_a_description():
    with pytest.raises(ConfigError, match="description"):
        param(1, "")


def test_config_files_finds_generated_files_and_reports_and_rewrites_stale_ones(tmp_path):
    config_dir = tmp_path / "pkg" / "config"
    config_dir.mkdir(parents=True)
    path = config_dir / "node.yaml"
    path.write_text(ExampleConfig.render_yaml("Parameters of the example node"))
    (config_dir / "other.yaml").write_text("# a hand-written file\nkey: 1\n")
    assert [(p.name, cls) for p, _, cls in generated_files(tmp_path)] == [("node.yaml", ExampleConfig)]
    assert stale_files(tmp_path) == []
    path.write_text(path.read_text().replace("rate: 10.0", "rate: 12.0"))
    assert stale_files(tmp_path) == [path]
    assert stale_files(tmp_path, write=True) == [path]
    assert stale_files(tmp_path) == []
    assert "rate: 10.0" in path.read_text()
