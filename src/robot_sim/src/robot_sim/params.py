"""The parameters of robot_sim's simulator nodes, one `NodeConfig` class per node (no ROS).

Each default is written here only: the YAML files in robot_sim's config/ that the launch files
load are generated from these classes (`python -m robot_common.config_files --write`), and the
nodes read their private parameters into them (`robot_common.ros_node.read_config`). Anything
that must agree with a running simulator (the demo, tests) reads the same YAML into the same
class with `load_config_file`.
"""
from dataclasses import dataclass
from pathlib import Path
from typing import Type, TypeVar, Union

import yaml

from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from robot_sim.building import LAYOUTS

__all__ = ["MapPublisherParams", "SensorSimParams", "UnicycleSimParams", "BuildingSimParams",
           "PeopleSimParams", "ObjectDetectionSimParams", "load_config_file"]

ConfigT = TypeVar("ConfigT", bound=NodeConfig)

_MAP_YAML_DOC = "map_server .yaml file; empty: the generated building floor of `seed`"
_LAYOUT_DOC = ("the generated floor (with an empty map_yaml): hall (one main hall and a back hall) "
               "or loop (plus west and north corridors: a second, quiet way round)")


def _layout():
    return param("hall", _LAYOUT_DOC, choices=LAYOUTS)


@dataclass
class MapPublisherParams(NodeConfig):
    """map_publisher: the map it publishes."""

    map_yaml: str = param("", _MAP_YAML_DOC)
    seed: int = param(0, "seed of the generated building")
    layout: str = _layout()
    frame_id: str = param("map", "frame of the map")
    labels_path: str = param("", "if set, the generated building's labels are written there "
                                 "(map_labelling JSON, for the region recommender)")


@dataclass
class SensorSimParams(NodeConfig):
    """sensor_sim: the patrolling mobile base and its sensors (a rate of 0 disables a topic)."""

    map_yaml: str = param("", _MAP_YAML_DOC)
    seed: int = param(0, "seed of the generated building")
    layout: str = _layout()
    speed: float = param(0.5, "patrol speed (m/s)")
    waypoints: list = param([[0.0, 0.0], [1.0, 0.0]],
                            "patrol [x, y] waypoints on a map file (the generated building: its hall)")
    odom_rate: float = param(50.0, "odom rate (Hz)")
    tf_rate: float = param(50.0, "odom -> base_link tf rate (Hz)")
    scan_rate: float = param(10.0, "laser scan rate (Hz)")
    image_rate: float = param(5.0, "camera image rate (Hz)")
    joint_rate: float = param(20.0, "wheel joint states rate (Hz)")
    scan_beams: int = param(360, "laser beams per scan")
    scan_range: float = param(10.0, "laser range (m)")
    image_width: int = param(320, "camera image width (pixels, rgb8)")
    image_height: int = param(240, "camera image height (pixels)")
    odom_frame: str = param("odom", "odometry frame")
    base_frame: str = param("base_link", "robot base frame")
    map_frame: str = param("map", "map frame (map -> odom is the identity)")
    laser_frame: str = param("laser", "laser frame (base_link -> laser: 0.1 m ahead)")
    crowd: bool = param(False, "simulate people: the laser sees them, `people` reports them as a "
                               "tracker would, `~people_truth` has the true people in view")
    crowd_hour: float = param(-1.0, "hour of the week (0 = Monday 00:00) of the people densities; "
                                    "negative: the time of week of the stamps (UTC)")
    peak_density: float = param(0.15, "people per m^2 in a main hall on a weekday afternoon",
                                minimum=0.0)
    crowd_seed: int = param(1, "seed of the people and the tracker's errors")
    person_radius: float = param(0.25, "radius of a person's disc (m)", minimum=0.0)
    miss_rate: float = param(0.1, "share of the scans in which the tracker misses a visible person")
    false_positive_rate: float = param(0.1, "share of the tracker's reported tracks that are false")
    false_track_scans: int = param(2, "scans a false track lasts", minimum=1)
    tracker_noise: float = param(0.05, "standard deviation of the tracked positions (m)",
                                 minimum=0.0)
    people_frame: str = param("odom", "frame of the tracked people")

    def check(self) -> None:
        if not (0 <= self.miss_rate < 1 and 0 <= self.false_positive_rate < 1):
            raise ConfigError(f"~miss_rate and ~false_positive_rate must be in [0, 1), got "
                              f"{self.miss_rate} and {self.false_positive_rate}")


@dataclass
class UnicycleSimParams(NodeConfig):
    """unicycle_sim: the scenario, its episodes and the simulated clock."""

    scenario: str = param("static_obstacle", "a scenario name (robot_sim config/scenarios) or YAML path")
    seed: int = param(0, "seed of the random starts")
    start: list = param([], "[x, y, yaw] of the first episode; []: a random start")
    time_scale: float = param(1.0, "simulated seconds per wall-clock second")
    command_timeout: float = param(0.5, "seconds after which a silent cmd_vel means stop")
    odom_frame: str = param("odom", "odometry frame")
    base_frame: str = param("base_link", "robot base frame")

    def check(self) -> None:
        if not self.time_scale > 0:
            raise ConfigError(f"~time_scale must be positive, got {self.time_scale!r}")


@dataclass
class BuildingSimParams(NodeConfig):
    """building_sim: a robot driven by cmd_vel on a floor among walking people."""

    map_yaml: str = param("", _MAP_YAML_DOC)
    seed: int = param(0, "seed of the generated building, the robot's start on a map file and "
                         "the people's routes")
    layout: str = _layout()
    start: list = param([], "[x, y, yaw] of the robot in the map frame; []: the generated "
                            "building's main hall 1.5 m from its west end facing east (a map "
                            "file: a spot 0.7 m clear of walls drawn from `seed`)")
    people: int = param(4, "people walking rounds through the halls (with crowd_hour < 0)",
                        minimum=0)
    crowd_hour: float = param(-1.0, "hour of the week (0 = Monday 00:00): as many people as the "
                                    "people model's halls hold then on average (up to "
                                    "max_people), placed by its densities; negative: `people`")
    peak_density: float = param(0.15, "people per m^2 in a main hall on a weekday afternoon "
                                      "(with crowd_hour)", minimum=0.0)
    max_people: int = param(30, "most people with crowd_hour", minimum=0)
    dt: float = param(0.05, "simulated seconds per step (odom, tf and cmd_vel_applied each step)")
    time_scale: float = param(1.0, "simulated seconds per wall-clock second")
    command_timeout: float = param(0.5, "simulated seconds after which a silent cmd_vel means stop",
                                   minimum=0.0)
    publish_clock: bool = param(False, "publish /clock (rosgraph_msgs/Clock) each step with the "
                                       "simulated time (steps x dt from 0, as Gazebo and Stage "
                                       "do), stamp every message and tf with it and step on the "
                                       "wall clock: for nodes run with /use_sim_time true")
    scan_rate: float = param(10.0, "scans (and people reports) per simulated second")
    scan_beams: int = param(360, "laser beams per scan (270 degrees)", minimum=2)
    scan_range: float = param(10.0, "laser range (m)")
    people_range: float = param(8.0, "the tracker reports people in sight within this range (m)")
    robot_radius: float = param(0.18, "the robot's disc (m): touching a wall, clutter or a person "
                                      "is a collision")
    obstacle_radius: float = param(0.3, "radius of a disc added on ~obstacles_in (m)")
    odom_frame: str = param("odom", "odometry frame (the same as the map frame: map -> odom is "
                                    "the identity)")
    base_frame: str = param("base_link", "robot base frame")
    map_frame: str = param("map", "map frame")
    laser_frame: str = param("laser", "laser frame (base_link -> laser: 0.1 m ahead)")
    people_frame: str = param("odom", "frame of the tracked people")

    def check(self) -> None:
        positive = {"dt": self.dt, "time_scale": self.time_scale, "scan_rate": self.scan_rate,
                    "scan_range": self.scan_range, "robot_radius": self.robot_radius,
                    "obstacle_radius": self.obstacle_radius}
        bad = {name: value for name, value in positive.items() if not value > 0}
        if bad:
            raise ConfigError(f"these parameters must be positive: {bad}")
        if self.start and len(self.start) != 3:
            raise ConfigError(f"~start is [x, y, yaw] or [], got {self.start!r}")


@dataclass
class PeopleSimParams(NodeConfig):
    """people_sim: simulated robots counting people in the halls, in simulated time."""

    map_yaml: str = param("", "map_server .yaml file; empty: the generated building of `seed` "
                              "(or the `map` topic, see use_map_topic)")
    use_map_topic: bool = param(False, "true: derive the halls from the first map on the `map` topic")
    seed: int = param(0, "seed of the generated building")
    layout: str = _layout()
    sim_seed: int = param(1, "seed of the places, times and counts")
    cell_size: float = param(0.5, "cell size (m)")
    robots: int = param(3, "number of simulated robots", minimum=1)
    rate: float = param(5.0, "views per wall-clock second, all robots together")
    time_scale: float = param(60.0, "simulated seconds per wall-clock second")
    start_hour: float = param(10.0, "hours since Monday 00:00 when the node starts")
    utc_offset_hours: float = param(0.0, "stamps are simulated times in this time zone")
    radius: float = param(4.0, "view radius (m)")
    duration: float = param(0.0, "seconds per view (0: snapshots)")
    total_counts: bool = param(False, "true: one count per view (radius mode) instead of per-cell counts")
    frame_id: str = param("map", "frame of the positions")

    def check(self) -> None:
        if not (self.rate > 0 and self.time_scale > 0 and self.radius > 0):
            raise ConfigError(f"~rate, ~time_scale and ~radius must be positive, got rate={self.rate}, "
                              f"time_scale={self.time_scale}, radius={self.radius}")


@dataclass
class ObjectDetectionSimParams(NodeConfig):
    """object_detection_sim: the noisy detections of a generated building's objects and places."""

    seed: int = param(0, "seed of the generated building")
    random_seed: int = param(1, "seed of the detection noise")
    mean_detections: float = param(20.0, "mean detections per object (Poisson)")
    noise_std: float = param(0.1, "position noise (m)")
    clutter_fraction: float = param(0.1, "fraction of detections that are clutter (< 1)")
    extent_spread: bool = param(True, "detections anywhere on an object's extent")
    with_size: bool = param(True, "report object sizes")
    place_detections: int = param(5, "noisy sightings of every labelled place", minimum=0)
    rate: float = param(500.0, "messages per second")
    frame_id: str = param("map", "frame of the detections")
    region_id: str = param("", "region id of every detection")

    def check(self) -> None:
        if not self.rate > 0:
            raise ConfigError(f"~rate must be positive, got {self.rate!r}")


def load_config_file(config_cls: Type[ConfigT], path: Union[str, Path]) -> ConfigT:
    """The parameters a launch file loads from `path` (a generated config YAML), checked."""
    try:
        values = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read parameter file {path}: {err}") from err
    if not isinstance(values, dict):
        raise ConfigError(f"parameter file {path} is not a YAML mapping")
    return config_cls.from_mapping(values)
