"""One parameter convention for every node of the workspace (no ROS here).

A node's parameters are a dataclass derived from `NodeConfig`, each field declared with `param()`:
its default and its description are written there and nowhere else. The node builds it from a
plain mapping (`Config.from_mapping(rospy.get_param("~", {}))`, see `robot_common.ros_node`), so
the same checks run in unit tests without a ROS master. The YAML files in a package's `config/`
that launch files load are generated from the class (`render_yaml`) and checked against it by the
workspace tests (`python -m robot_common.config_files --write` regenerates them).

    @dataclass
    class ControllerConfig(NodeConfig):
        rate: float = param(10.0, "control cycles per second", minimum=0.0)
        frame: str = param("odom", "frame of the poses it plans in")

Values are checked against the field's type (an int is accepted for a float, nothing else is
converted), against `choices` and `minimum`, then by the class's own `check()`. Unknown keys are
errors: a misspelt parameter would otherwise be ignored silently.
"""
import copy
import math
import typing
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Type, TypeVar

import yaml

from robot_common.errors import ConfigError

__all__ = ["NodeConfig", "param"]

ConfigT = TypeVar("ConfigT", bound="NodeConfig")


def param(default: Any, doc: str, *, choices: Optional[Sequence[Any]] = None,
          minimum: Optional[float] = None):
    """A node parameter: its one default, a one-line description, optional allowed values."""
    if not doc:
        raise ConfigError("every parameter needs a description")
    metadata = {"doc": doc, "choices": tuple(choices) if choices is not None else None,
                "minimum": minimum}
    if isinstance(default, (dict, list)):
        return field(default_factory=lambda: copy.deepcopy(default), metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass
class NodeConfig:
    """Base of the nodes' parameter classes (see the module docstring)."""

    @classmethod
    def from_mapping(cls: Type[ConfigT], params: Optional[Mapping[str, Any]] = None, *,
                     ignore: Iterable[str] = ()) -> ConfigT:
        """Checked parameters from a mapping (missing keys take their defaults)."""
        params = dict(params or {})
        for key in ignore:
            params.pop(key, None)
        known = {spec.name for spec in fields(cls)}
        unknown = sorted(set(params) - known)
        if unknown:
            raise ConfigError(f"unknown parameter(s) {', '.join('~' + k for k in unknown)}; "
                              f"known: {', '.join(sorted(known))}")
        hints = typing.get_type_hints(cls)
        values = {}
        for spec in fields(cls):
            if spec.name in params:
                values[spec.name] = _checked(spec, hints[spec.name], params[spec.name])
        config = cls(**values)
        config.check()
        return config

    def check(self) -> None:
        """Checks across parameters; subclasses raise ConfigError naming the bad value."""

    def to_dict(self) -> Dict[str, Any]:
        return {spec.name: copy.deepcopy(getattr(self, spec.name)) for spec in fields(self)}

    @classmethod
    def defaults(cls) -> Dict[str, Any]:
        """Every parameter's default, as plain data."""
        return {spec.name: _default_of(spec) for spec in fields(cls)}

    @classmethod
    def describe(cls) -> List[Tuple[str, Any, str]]:
        """(name, default, description) of every parameter, in declaration order."""
        return [(spec.name, _default_of(spec), spec.metadata.get("doc", ""))
                for spec in fields(cls)]

    @classmethod
    def render_yaml(cls, title: str) -> str:
        """The config/*.yaml text for this class: a header, then each parameter with its doc."""
        lines = [f"# {title}",
                 f"# Generated from {cls.__module__}:{cls.__qualname__}; the defaults are written",
                 "# there. Regenerate with: python -m robot_common.config_files --write", ""]
        for name, default, doc in cls.describe():
            lines.append(f"# {doc}")
            dumped = yaml.safe_dump({name: default}, default_flow_style=False, sort_keys=False,
                                    width=100).rstrip("\n")
            lines.extend(dumped.splitlines())
        return "\n".join(lines) + "\n"


def _default_of(spec) -> Any:
    if spec.default is not MISSING:
        return spec.default
    if spec.default_factory is not MISSING:  # type: ignore[misc]
        return spec.default_factory()  # type: ignore[misc]
    raise ConfigError(f"parameter {spec.name} has no default")


def _checked(spec, hint: Any, value: Any) -> Any:
    name = spec.name
    value = _typed(name, hint, value)
    choices = spec.metadata.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"~{name} must be one of {list(choices)}, got {value!r}")
    minimum = spec.metadata.get("minimum")
    if minimum is not None and value is not None and not value >= minimum:
        raise ConfigError(f"~{name} must be >= {minimum}, got {value!r}")
    return value


def _typed(name: str, hint: Any, value: Any) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union:
        if value is None and type(None) in args:
            return None
        hint = next(arg for arg in args if arg is not type(None))
        return _typed(name, hint, value)
    if hint is Any:
        return value
    base = origin or hint
    if base is bool:
        if isinstance(value, bool):
            return value
    elif base is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif base is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if math.isnan(float(value)):
                raise ConfigError(f"~{name} must be a number, got {value!r}")
            return float(value)
    elif base is str:
        if isinstance(value, str):
            return value
    elif base in (dict, Dict, Mapping):
        if isinstance(value, Mapping):
            return dict(value)
    elif base in (list, List, Sequence, tuple):
        if isinstance(value, (list, tuple)):
            return list(value)
    else:
        return value
    raise ConfigError(f"~{name} must be a {getattr(base, '__name__', base)}, got {value!r}")
