"""The layer server's parameters (`LayerServerParams`, a robot_common.params class; no rospy
here) and their conversion into the layers' objects (`LayerServerConfig`: LayerParams per region,
ClassHierarchy, colours).

config/igmm_layers.yaml is generated from LayerServerParams, where each default is written once
(the per-layer defaults are LayerParams'); `python -m robot_common.config_files --write`
regenerates it. Bad values raise robot_common's ConfigError naming the parameter.
"""
import math
from dataclasses import asdict, dataclass, field
from typing import Dict, List, Mapping, Tuple

from igmm_layers.errors import InvalidInputError, UnknownNameError
from igmm_layers.hierarchy import ClassHierarchy
from igmm_layers.layers import LayerParams, LayerSet, check_kind
from igmm_layers.queries import DEFAULT_MAX_DISTANCE, DEFAULT_PAIR_METHOD, PAIR_METHODS
from robot_common.errors import ConfigError
from robot_common.params import param
from ros_mongo.params import CentralSourceParams

__all__ = ["LayerServerParams", "LayerServerConfig"]


_LAYER_DEFAULTS = {name: value for name, value in asdict(LayerParams()).items()
                   if name != "observation_topic"}
_CLASS_HIERARCHY = {
    "furniture": ["chair", "table", "desk", "couch"],
    "appliance": ["fridge", "microwave", "printer", "computer", "vending_machine"],
    "fixture": ["sink", "whiteboard", "water_fountain", "trash_can", "plant"],
}
_CLASS_COLOURS = {
    "chair": [0.90, 0.10, 0.29], "table": [0.24, 0.71, 0.29], "desk": [0.00, 0.51, 0.78],
    "couch": [0.96, 0.51, 0.19], "whiteboard": [0.57, 0.12, 0.71], "computer": [0.27, 0.94, 0.94],
    "fridge": [0.94, 0.20, 0.90], "microwave": [0.82, 0.96, 0.24], "sink": [0.00, 0.50, 0.50],
    "printer": [0.67, 0.43, 0.16], "trash_can": [0.50, 0.00, 0.00], "plant": [0.50, 0.50, 0.00],
    "water_fountain": [0.00, 0.00, 0.50], "vending_machine": [1.00, 0.88, 0.10],
}


@dataclass
class LayerServerParams(CentralSourceParams):
    """The layer server's private parameters as given (node `igmm_layers`)."""

    map_frame: str = param("map", "frame of all clusters; observations in other frames are "
                           "transformed into it with tf2")
    default_region: str = param("default", "region of observations whose region_id is empty")
    observation_topic: str = param("observations", "shared topic (robot_common/ObjectObservation) "
                                   "of the objects layers; relative names are private")
    place_observation_topic: str = param("place_observations", "shared topic of the regions "
                                         "layers (labelled places); relative names are private")
    layer_defaults: dict = param(_LAYER_DEFAULTS, "parameters of every layer (igmm_layers.LayerParams; "
                                 "see the README)")
    regions: list = param([], "per-region layers {region_id, kind, observation_topic, <layer "
                          "parameters>}; observation_topic: that layer's own topic")
    class_hierarchy: dict = param(_CLASS_HIERARCHY, "groups of classes: a query for a group "
                                  "covers its classes (groups may contain groups)")
    class_colours: dict = param(_CLASS_COLOURS, "marker colour [r, g, b] in [0, 1] per class; "
                                "other classes get a hue from their name")
    marker_rate: float = param(2.0, "Hz of ~markers/<region>/<kind> while someone listens; 0: none",
                               minimum=0.0)
    pair_method: str = param(DEFAULT_PAIR_METHOD, "default method of the object pair likelihood",
                             choices=PAIR_METHODS)
    pair_max_distance: float = param(DEFAULT_MAX_DISTANCE, "range (m) of the object pair likelihood")
    db_url: str = param("", "database of save_clusters/load_clusters (CouchDB http://... or "
                        "MongoDB mongodb://...); '': none")
    robot_id: str = param("", "robot id stored with saved cluster sets (a fleet's central database "
                              "tells whose they are); '': none")
    tf_timeout: float = param(0.2, "seconds to wait for a transform into map_frame before an "
                              "observation is dropped", minimum=0.0)
    queue_size: int = param(10000, "observations waiting to be learnt; more are dropped (and "
                            "counted in ~layer_info)", minimum=1)
    central_clusters: bool = param(False, "source central: also fold in the cluster sets robots "
                                          "saved (each cluster one observation at its mean); off "
                                          "when their detections are replicated too")


@dataclass
class LayerServerConfig:
    """The layer server's configuration, converted from its LayerServerParams (which hold the defaults)."""

    map_frame: str
    default_region: str
    observation_topic: str
    place_observation_topic: str
    layer_defaults: LayerParams
    regions: Dict[Tuple[str, str], LayerParams]
    hierarchy: ClassHierarchy
    class_colours: Dict[str, Tuple[float, float, float]]
    marker_rate: float
    pair_method: str
    pair_max_distance: float
    db_url: str
    tf_timeout: float
    queue_size: int
    robot_id: str = ""
    central: CentralSourceParams = field(default_factory=CentralSourceParams)  # where from
    central_clusters: bool = False

    @property
    def source(self) -> str:
        """"topic" (the observation topics) or "central" (the fleet database's feed)."""
        return self.central.source

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> "LayerServerConfig":
        """Check and convert the node's private parameters (unknown keys are errors)."""
        return cls.from_node_params(LayerServerParams.from_mapping(params))

    @classmethod
    def from_node_params(cls, raw: LayerServerParams) -> "LayerServerConfig":
        """Convert checked parameters into the layers' objects (ConfigError if they are bad)."""
        try:
            return cls._converted(raw)
        except (InvalidInputError, UnknownNameError) as err:  # found by LayerParams, check_kind
            raise ConfigError(str(err)) from err

    @classmethod
    def _converted(cls, raw: LayerServerParams) -> "LayerServerConfig":
        layer_defaults = LayerParams.from_dict(raw.layer_defaults)
        config = cls(map_frame=raw.map_frame, default_region=raw.default_region,
                     observation_topic=raw.observation_topic,
                     place_observation_topic=raw.place_observation_topic,
                     layer_defaults=layer_defaults,
                     regions=_regions(raw.regions, layer_defaults),
                     hierarchy=ClassHierarchy(raw.class_hierarchy),
                     class_colours=_colours(raw.class_colours), marker_rate=raw.marker_rate,
                     pair_method=raw.pair_method, pair_max_distance=raw.pair_max_distance,
                     db_url=raw.db_url, tf_timeout=raw.tf_timeout, queue_size=raw.queue_size,
                     robot_id=raw.robot_id,
                     central=CentralSourceParams(raw.source, raw.central_url,
                                                 raw.central_credentials_file,
                                                 list(raw.central_topics)),
                     central_clusters=raw.central_clusters)
        config.check()
        return config

    def check(self) -> None:
        if not self.map_frame or not self.default_region:
            raise ConfigError("map_frame and default_region must not be empty")
        if self.pair_method not in PAIR_METHODS:
            raise ConfigError(f"pair_method must be one of {PAIR_METHODS}, got {self.pair_method!r}")
        for key in ("marker_rate", "pair_max_distance", "tf_timeout"):
            if not math.isfinite(getattr(self, key)):
                raise ConfigError(f"{key} must be finite, got {getattr(self, key)!r}")
        if not (self.pair_max_distance > 0 and self.marker_rate >= 0 and self.tf_timeout >= 0
                and self.queue_size >= 1):
            raise ConfigError("need pair_max_distance > 0, marker_rate >= 0, tf_timeout >= 0 "
                                    "and queue_size >= 1")

    def layer_set(self) -> LayerSet:
        return LayerSet(defaults=self.layer_defaults, region_params=self.regions,
                        hierarchy=self.hierarchy, default_region=self.default_region)


def _mapping(value: object, key: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise ConfigError(f"{key} must be a mapping, got {value!r}")
    return value


def _regions(entries: object, defaults: LayerParams) -> Dict[Tuple[str, str], LayerParams]:
    if not isinstance(entries, (list, tuple)):
        raise ConfigError(f"regions must be a list of {{region_id, kind, ...}}, got {entries!r}")
    regions: Dict[Tuple[str, str], LayerParams] = {}
    for entry in entries:
        entry = dict(_mapping(entry, "regions entry"))
        region_id = str(entry.pop("region_id", "") or "")
        if not region_id:
            raise ConfigError(f"regions entry without region_id: {entry!r}")
        kind = check_kind(str(entry.pop("kind", "objects")))
        if (region_id, kind) in regions:
            raise ConfigError(f"region {region_id!r} layer {kind!r} configured twice")
        regions[(region_id, kind)] = LayerParams.from_dict(entry, defaults)
    return regions


def _colours(value: object) -> Dict[str, Tuple[float, float, float]]:
    colours: Dict[str, Tuple[float, float, float]] = {}
    for name, rgb in _mapping(value, "class_colours").items():
        values: List[float] = list(rgb) if isinstance(rgb, (list, tuple)) else []
        if len(values) != 3 or not all(isinstance(v, (int, float)) and 0 <= v <= 1 for v in values):
            raise ConfigError(f"class_colours[{name!r}] must be [r, g, b] in [0, 1], got {rgb!r}")
        colours[str(name)] = (float(values[0]), float(values[1]), float(values[2]))
    return colours
