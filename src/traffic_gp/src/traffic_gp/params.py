"""The parameters of traffic_gp's nodes (`traffic_server`, node name `traffic_gp`; and
`people_counter`); no ROS here.

`TrafficServerParams` and `PeopleCounterParams` are the one place their defaults and
descriptions are written: the nodes read them with `robot_common.ros_node.read_config`, and
config/traffic_gp.yaml and config/people_counter.yaml are generated from them
(`python -m robot_common.config_files --write`). `utc_offset_hours` also accepts "" and "local"
(the machine's local zone, like None) and a number written as a string.
"""
from dataclasses import dataclass
from typing import Any, Mapping, Optional

from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from ros_mongo.params import CentralSourceParams

__all__ = ["TrafficServerParams", "PeopleCounterParams", "LOCAL_ZONE"]

LOCAL_ZONE = ("", "local")     # utc_offset_hours values that mean the machine's local zone


@dataclass
class TrafficServerParams(CentralSourceParams):
    """Parameters of the crowd-model server (see `ros_traffic.TrafficServer`)."""

    map_yaml: str = param("", "map_server .yaml of the map; empty: the map from the `map` topic")
    cell_size: float = param(0.5, "cell side in metres (a whole number of map cells)")
    model_path: str = param("", "model file: loaded at start if it exists (no retraining); "
                                "~save_model writes here")
    save_on_shutdown: bool = param(False, "save the model to model_path when the node stops")
    utc_offset_hours: Optional[float] = param(
        None, "time zone of the stamps, hours east of UTC; null, '' or 'local': the machine's zone")
    clock: str = param("ros", "now is ROS time (ros) or the newest observation stamp "
                              "(observations; simulations)", choices=("ros", "observations"))
    dwell_time: float = param(20.0, "s; counts over a watch of d seconds: exposure x "
                                    "(1 + d / dwell_time)")
    min_rows: int = param(2000, "observation rows before the first fit (the baselines are "
                                "served at once, the GP is chosen and fitted in the background)")
    initial_steps: int = param(600, "maximum training steps of a GP fit in the background (the "
                                    "first and each refit; after its choice of settings on the "
                                    "most recent days)")
    refit_growth: float = param(2.0, "refit the GP in the background (its chosen settings, warm "
                                     "start; served forecaster and intervals chosen again on the "
                                     "most recent days) whenever the rows have grown this many "
                                     "times since the last fit; 0: never", minimum=0.0)
    reselect_growth: float = param(8.0, "choose the GP's settings again (candidates screened on a "
                                        "sample of at most screen_rows rows) whenever the rows "
                                        "have grown this many times since the last choice; 0: "
                                        "never", minimum=0.0)
    train_period: float = param(2.0, "s between training rounds")
    chunk_steps: int = param(20, "training steps per lock hold (services wait at most one chunk)")
    publish_period: float = param(5.0, "s between cost map publications")
    lookahead_minutes: float = param(30.0, "minutes ahead the window cost map looks")
    lookahead_step_minutes: float = param(5.0, "minutes between the times of the window cost map")
    saturation_density: float = param(1.0, "people per m^2 that cost 95")
    wall_value: int = param(-1, "value of walls and unknown cells: -1 (leave walls to the map's "
                                "static layer) or 100 (lethal)", choices=(-1, 100))
    full_resolution: bool = param(True, "cost maps at the map's resolution (a static layer "
                                        "resizes to it)")
    frame_id: str = param("map", "frame of the published cost maps")
    model: dict = param({}, "TrafficGP keyword arguments (empty: TrafficGP's defaults)")

    @classmethod
    def from_mapping(cls, params: Optional[Mapping[str, Any]] = None,
                     **kwargs) -> "TrafficServerParams":
        """As `NodeConfig.from_mapping`; utc_offset_hours "" / "local" mean None (local zone)."""
        params = dict(params or {})
        offset = params.get("utc_offset_hours")
        if isinstance(offset, str):
            if offset in LOCAL_ZONE:
                params["utc_offset_hours"] = None
            else:
                try:
                    params["utc_offset_hours"] = float(offset)
                except ValueError as err:
                    raise ConfigError(f"~utc_offset_hours must be hours east of UTC or '' / "
                                      f"'local', got {offset!r}") from err
        return super().from_mapping(params, **kwargs)


@dataclass
class PeopleCounterParams(NodeConfig):
    """Parameters of the people counter (see `ros_counter.PeopleCounterNode`)."""

    map_yaml: str = param("", "map_server .yaml of the map; empty: the map from the `map` topic")
    cell_size: float = param(0.5, "cell side in metres (the crowd model's cell_size)")
    robot_id: str = param("", "robot id of the counts; empty: the global /robot_id parameter, "
                              "else the host name")
    watch: float = param(10.0, "seconds of scans per PeopleCount message", minimum=0.1)
    max_range: float = param(8.0, "metres of each scan used for counting (the scanner's "
                                  "range_max caps it too)")
    person_radius: float = param(0.25, "metres; a person's disc hides what is behind it",
                                 minimum=0.0)
    dwell_time: float = param(20.0, "seconds a person stays in view of one cell (the crowd "
                                    "model's dwell_time)")
    min_detections: int = param(3, "detections (people messages) a track needs before it "
                                   "counts", minimum=1)
    max_gap: float = param(0.5, "the most seconds one scan stands for", minimum=0.01)
    people_timeout: float = param(0.5, "s; a scan is used with the people message nearest its "
                                       "stamp within this; a scan without one is not used",
                                  minimum=0.0)
    tf_timeout: float = param(0.5, "s to wait for the map -> laser transform of a scan",
                              minimum=0.0)
    map_frame: str = param("map", "frame of the map and of the published counts")
    confirm_time: float = param(1.0, "s of scans an ended watch waits before it is published "
                                     "(at most half the watch): a person first seen at its end "
                                     "still counts in it once their track is confirmed",
                                minimum=0.0)

    def make_counter(self, cells, **overrides):
        """The counter's core (`counting.PeopleCounter`) with these settings on `cells`."""
        from traffic_gp.counting import PeopleCounter

        settings = dict(watch=self.watch, max_range=self.max_range,
                        person_radius=self.person_radius, dwell_time=self.dwell_time,
                        min_detections=self.min_detections, max_gap=self.max_gap)
        settings.update(overrides)
        settings.setdefault("confirm_time", min(self.confirm_time, settings["watch"] / 2))
        return PeopleCounter(cells, **settings)

    def check(self) -> None:
        if not (self.cell_size > 0 and self.max_range > 0 and self.dwell_time > 0):
            raise ConfigError(f"~cell_size, ~max_range and ~dwell_time must be positive, got "
                              f"{self.cell_size}, {self.max_range}, {self.dwell_time}")
