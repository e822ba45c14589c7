"""The launch files resolve as roslaunch reads them (every include, arg and parameter file), start
the nodes they promise and hand the errand server what the arguments say; no ROS master."""
import subprocess

import pytest
import yaml


def roslaunch(*args: str) -> str:
    done = subprocess.run(["roslaunch", *args], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_robot_launch_brings_up_the_whole_robot_and_the_recorder_on_request():
    nodes = set(roslaunch("--nodes", "errand_nav", "errands.launch").split())
    assert nodes == {"/traffic_gp", "/embedding_server", "/region_recommender",
                     "/reward_controller", "/errand_server"}
    recording = set(roslaunch("--nodes", "errand_nav", "errands.launch", "record:=true").split())
    assert recording - nodes == {"/ros_mongo_server"}


@pytest.mark.parametrize("crowd, service", [("true", "traffic_gp/predict_density"),
                                            ("false", "")])
def test_the_errand_server_is_told_where_the_crowd_forecast_is(crowd, service):
    params = yaml.safe_load(roslaunch("--dump-params", "errand_nav", "errands.launch",
                                      f"with_crowd_model:={crowd}", "map_yaml:=floor.yaml"))
    assert params["/errand_server/density_service"] == service
    assert params["/errand_server/map_yaml"] == "floor.yaml"
    assert params["/errand_server/controller_frame"] == "odom"
    assert params["/reward_controller/frame"] == "odom"


def test_the_simulation_launch_adds_the_simulated_robot(workspace_root):
    nodes = set(roslaunch("--nodes", str(workspace_root / "launch" / "errands_sim.launch"))
                .split())
    assert {"/map_publisher", "/building_sim", "/reward_controller", "/errand_server"} == nodes
    params = yaml.safe_load(roslaunch("--dump-params", str(workspace_root / "launch" /
                                                           "errands_sim.launch"),
                                      "errand_params:={blocked_after: 3.0}"))
    assert params["/errand_server/blocked_after"] == 3.0
    assert params["/errand_server/density_service"] == ""


def test_a_second_simulated_robot_lives_in_its_namespace_with_its_own_frames(workspace_root):
    launch = str(workspace_root / "launch" / "errands_sim.launch")
    args = ["ns:=/errand_robot", "frame_prefix:=errand_robot/"]
    nodes = set(roslaunch("--nodes", launch, *args).split())
    assert nodes == {"/errand_robot/map_publisher", "/errand_robot/building_sim",
                     "/errand_robot/reward_controller", "/errand_robot/errand_server"}
    params = yaml.safe_load(roslaunch("--dump-params", launch, *args))
    assert params["/errand_robot/building_sim/base_frame"] == "errand_robot/base_link"
    assert params["/errand_robot/errand_server/base_frame"] == "errand_robot/base_link"
    assert params["/errand_robot/reward_controller/frame"] == "errand_robot/odom"
