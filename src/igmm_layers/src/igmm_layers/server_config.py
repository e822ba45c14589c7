"""The layer server's configuration from its ROS parameters (a plain dict; no rospy here).

Defaults live in config/igmm_layers.yaml; every key is documented there and in the README.
"""
import math
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Tuple

from igmm_layers.errors import InvalidInputError
from igmm_layers.hierarchy import ClassHierarchy
from igmm_layers.layers import LayerParams, LayerSet, check_kind
from igmm_layers.queries import DEFAULT_MAX_DISTANCE, DEFAULT_PAIR_METHOD, PAIR_METHODS

__all__ = ["ServerConfig"]

_KEYS = ("map_frame", "default_region", "observation_topic", "place_observation_topic",
         "layer_defaults", "regions", "class_hierarchy", "class_colours", "marker_rate",
         "pair_method", "pair_max_distance", "db_url", "tf_timeout", "queue_size")


@dataclass
class ServerConfig:
    map_frame: str = "map"
    default_region: str = "default"
    observation_topic: str = "observations"
    place_observation_topic: str = "place_observations"
    layer_defaults: LayerParams = field(default_factory=LayerParams)
    regions: Dict[Tuple[str, str], LayerParams] = field(default_factory=dict)
    hierarchy: ClassHierarchy = field(default_factory=ClassHierarchy)
    class_colours: Dict[str, Tuple[float, float, float]] = field(default_factory=dict)
    marker_rate: float = 2.0
    pair_method: str = DEFAULT_PAIR_METHOD
    pair_max_distance: float = DEFAULT_MAX_DISTANCE
    db_url: str = ""
    tf_timeout: float = 0.2
    queue_size: int = 10000

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> "ServerConfig":
        """Check and convert the node's private parameters (unknown keys are errors)."""
        unknown = sorted(set(params) - set(_KEYS))
        if unknown:
            raise InvalidInputError(f"unknown parameter(s) {unknown}; known: {sorted(_KEYS)}")
        config = cls()
        for key in ("map_frame", "default_region", "observation_topic", "place_observation_topic",
                    "db_url", "pair_method"):
            if key in params:
                setattr(config, key, str(params[key]))
        for key in ("marker_rate", "pair_max_distance", "tf_timeout"):
            if key in params:
                setattr(config, key, _number(params[key], key))
        if "queue_size" in params:
            config.queue_size = int(_number(params["queue_size"], "queue_size"))
        config.layer_defaults = LayerParams.from_dict(_mapping(params.get("layer_defaults", {}),
                                                               "layer_defaults"))
        config.regions = _regions(params.get("regions", []), config.layer_defaults)
        config.hierarchy = ClassHierarchy(_mapping(params.get("class_hierarchy", {}), "class_hierarchy"))
        config.class_colours = _colours(params.get("class_colours", {}))
        config.check()
        return config

    def check(self) -> None:
        if not self.map_frame or not self.default_region:
            raise InvalidInputError("map_frame and default_region must not be empty")
        if self.pair_method not in PAIR_METHODS:
            raise InvalidInputError(f"pair_method must be one of {PAIR_METHODS}, got {self.pair_method!r}")
        if not (self.pair_max_distance > 0 and self.marker_rate >= 0 and self.tf_timeout >= 0
                and self.queue_size >= 1):
            raise InvalidInputError("need pair_max_distance > 0, marker_rate >= 0, tf_timeout >= 0 "
                                    "and queue_size >= 1")

    def layer_set(self) -> LayerSet:
        return LayerSet(defaults=self.layer_defaults, region_params=self.regions,
                        hierarchy=self.hierarchy, default_region=self.default_region)


def _number(value: object, key: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{key} must be a number, got {value!r}") from err
    if not math.isfinite(number):
        raise InvalidInputError(f"{key} must be finite, got {value!r}")
    return number


def _mapping(value: object, key: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise InvalidInputError(f"{key} must be a mapping, got {value!r}")
    return value


def _regions(entries: object, defaults: LayerParams) -> Dict[Tuple[str, str], LayerParams]:
    if not isinstance(entries, (list, tuple)):
        raise InvalidInputError(f"regions must be a list of {{region_id, kind, ...}}, got {entries!r}")
    regions: Dict[Tuple[str, str], LayerParams] = {}
    for entry in entries:
        entry = dict(_mapping(entry, "regions entry"))
        region_id = str(entry.pop("region_id", "") or "")
        if not region_id:
            raise InvalidInputError(f"regions entry without region_id: {entry!r}")
        kind = check_kind(str(entry.pop("kind", "objects")))
        if (region_id, kind) in regions:
            raise InvalidInputError(f"region {region_id!r} layer {kind!r} configured twice")
        regions[(region_id, kind)] = LayerParams.from_dict(entry, defaults)
    return regions


def _colours(value: object) -> Dict[str, Tuple[float, float, float]]:
    colours: Dict[str, Tuple[float, float, float]] = {}
    for name, rgb in _mapping(value, "class_colours").items():
        values: List[float] = list(rgb) if isinstance(rgb, (list, tuple)) else []
        if len(values) != 3 or not all(isinstance(v, (int, float)) and 0 <= v <= 1 for v in values):
            raise InvalidInputError(f"class_colours[{name!r}] must be [r, g, b] in [0, 1], got {rgb!r}")
        colours[str(name)] = (float(values[0]), float(values[1]), float(values[2]))
    return colours
