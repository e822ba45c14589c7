"""The simulator nodes' parameter classes and node classes, without a ROS master."""
from pathlib import Path

import numpy as np
import pytest

from robot_common.errors import ConfigError, MapError
from robot_sim.detections import building_detections, place_sightings
from robot_sim.params import (
    BuildingSimParams,
    MapPublisherParams,
    ObjectDetectionSimParams,
    PeopleSimParams,
    SensorSimParams,
    UnicycleSimParams,
    load_config_file,
)
from robot_sim.ros_building_sim import BuildingSim
from robot_sim.ros_detections import DetectionSim
from robot_sim.ros_map_publisher import MapPublisher
from robot_sim.ros_people import PeopleSimNode
from robot_sim.ros_sensors import SensorSim
from robot_sim.ros_unicycle import UnicycleSim

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
FILES = {"map_publisher.yaml": MapPublisherParams, "sensor_sim.yaml": SensorSimParams,
         "unicycle_sim.yaml": UnicycleSimParams, "people_sim.yaml": PeopleSimParams,
         "object_detection_sim.yaml": ObjectDetectionSimParams, "building_sim.yaml": BuildingSimParams}


@pytest.mark.parametrize("name", sorted(FILES))
def test_the_launch_files_parameter_files_hold_the_class_defaults(name):
    config_cls = FILES[name]
    assert load_config_file(config_cls, CONFIG_DIR / name) == config_cls()


def test_parameters_are_checked_by_name_type_and_range():
    with pytest.raises(ConfigError, match="~robots must be >= 1"):
        PeopleSimParams.from_mapping({"robots": 0})
    with pytest.raises(ConfigError, match="~rate, ~time_scale and ~radius must be positive"):
        PeopleSimParams.from_mapping({"time_scale": 0.0})
    with pytest.raises(ConfigError, match="unknown parameter"):
        SensorSimParams.from_mapping({"scan_rays": 10})
    with pytest.raises(ConfigError, match="~time_scale must be positive"):
        UnicycleSimParams.from_mapping({"time_scale": -1.0})
    with pytest.raises(ConfigError, match="~rate must be positive"):
        ObjectDetectionSimParams.from_mapping({"rate": 0})
    assert SensorSimParams.from_mapping({"odom_rate": 0}).odom_rate == 0.0


def test_a_missing_parameter_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read parameter file"):
        load_config_file(PeopleSimParams, tmp_path / "none.yaml")


def test_map_publisher_reads_the_generated_building_or_fails_on_a_missing_file(tmp_path):
    publisher = MapPublisher(MapPublisherParams(seed=2))
    assert publisher.building is not None and publisher.grid is publisher.building.grid
    with pytest.raises(MapError, match="cannot read map file"):
        MapPublisher(MapPublisherParams(map_yaml=str(tmp_path / "missing.yaml")))


def test_sensor_sim_patrols_the_generated_hall_with_the_configured_sensors():
    sim = SensorSim(SensorSimParams(scan_beams=90, image_width=32, image_height=24))
    state = sim.path.state(3.0)
    assert len(sim.sensors.scan(state)) == 90
    assert sim.sensors.image(state).shape == (24, 32, 3)


def test_unicycle_sim_starts_where_it_is_told():
    sim = UnicycleSim(UnicycleSimParams(start=[0.5, 0.25, 0.0]))
    assert sim.episode.state[:3].tolist() == [0.5, 0.25, 0.0]


def test_detection_sim_publishes_what_building_detections_says():
    config = ObjectDetectionSimParams(mean_detections=3.0, place_detections=2)
    sim = DetectionSim(config)
    building, detections = building_detections(config)
    sightings = place_sightings(building, config)
    assert len(sim.objects) == len(detections) and len(sim.places) == len(sightings)
    assert len(sightings) == 2 * len(building.labels)
    assert sim.objects[0].class_name == detections.class_names[0]
    assert np.isclose(sim.places[-1].position.x, sightings[-1][1][0])


def test_people_sim_builds_the_generated_building_or_a_given_map():
    node = PeopleSimNode(PeopleSimParams(cell_size=1.0))
    from_map = PeopleSimNode(PeopleSimParams(cell_size=1.0), grid=node.sim.cells.grid)
    assert from_map.sim.cells.n_cells == node.sim.cells.n_cells > 0


def test_sensor_sim_with_a_crowd_builds_its_people_and_tracker_from_the_parameters():
    sim = SensorSim(SensorSimParams.from_mapping({"crowd": True, "miss_rate": 0.2,
                                                  "false_positive_rate": 0.05, "seed": 0}))
    assert sim.crowd is not None and sim.crowd.radius == 0.25
    assert (sim.tracker.miss_rate, sim.tracker.false_positive_rate) == (0.2, 0.05)
    assert SensorSim(SensorSimParams(seed=0)).crowd is None
    with pytest.raises(ConfigError, match="~miss_rate and ~false_positive_rate must be in"):
        SensorSimParams.from_mapping({"miss_rate": 1.0})


def test_building_sim_builds_its_floor_people_and_robot_from_the_parameters(tmp_path):
    sim = BuildingSim(BuildingSimParams(people=3, start=[3.0, 6.7, 0.0], scan_beams=90))
    assert len(sim.sim.scene.people) == 3 and sim.sim.state[:3].tolist() == [3.0, 6.7, 0.0]
    assert len(sim.sensors.scan_angles) == 90 and sim.scan_every == 2   # 10 Hz at 0.05 s steps
    # Monday 14:00: the people model's halls hold 10-20 people on average (test_floor_sim)
    crowd = BuildingSim(BuildingSimParams(crowd_hour=14.0))
    assert 10 <= len(crowd.sim.scene.people) <= 20
    assert len(BuildingSim(BuildingSimParams(crowd_hour=14.0, max_people=5)).sim.scene.people) == 5
    with pytest.raises(MapError, match="cannot read map file"):
        BuildingSim(BuildingSimParams(map_yaml=str(tmp_path / "missing.yaml")))
    with pytest.raises(ConfigError, match="must be positive"):
        BuildingSimParams.from_mapping({"dt": 0.0})
    with pytest.raises(ConfigError, match=r"~start is \[x, y, yaw\]"):
        BuildingSimParams.from_mapping({"start": [1.0, 2.0]})


def test_every_node_on_a_generated_floor_takes_the_loop_layout():
    loop = {"layout": "loop"}
    assert MapPublisher(MapPublisherParams(**loop)).grid.origin == (-2.5, 0.0, 0.0)
    assert SensorSim(SensorSimParams(scan_beams=8, **loop)).sensors.grid.origin[0] == -2.5
    assert BuildingSim(BuildingSimParams(people=0, **loop)).sim.planner.grid.origin[0] == -2.5
    names = PeopleSimNode(PeopleSimParams(cell_size=1.0, **loop)).sim.layout.names
    assert names[2:] == ["west_corridor", "north_corridor"]
    assert PeopleSimNode(PeopleSimParams(cell_size=1.0)).sim.layout.names == ["main_hall",
                                                                              "back_hall"]
