"""The demo program without running it: its chapters, its options, the simulator parameters it reads."""
import pytest

from robot_demo.app import CHAPTERS, Demo, parse_args, workspace_root
from robot_sim.params import ObjectDetectionSimParams, PeopleSimParams


def test_the_chapters_run_in_the_documented_order_and_each_has_a_title():
    assert list(CHAPTERS) == ["robot", "data_api", "object_layers", "region_search", "crowd_map",
                              "demonstrations", "fleet"]
    assert all(module.TITLE and callable(module.run) for module in CHAPTERS.values())


def test_options(tmp_path):
    args = parse_args(["--only", "robot", "crowd_map", "--output", str(tmp_path)])
    assert args.only == ["robot", "crowd_map"] and args.output == tmp_path and not args.keep_running
    with pytest.raises(SystemExit):
        parse_args(["--only", "no_such_chapter"])


def test_composed_launch_files_are_in_the_workspace_launch_folder():
    for name in ("crowd_sim.launch", "object_layers_sim.launch", "demo.launch", "demo.rviz"):
        assert (workspace_root() / "launch" / name).is_file()
    assert Demo.workspace_launch("crowd_sim.launch").endswith("launch/crowd_sim.launch")


def test_simulator_parameters_come_from_the_files_the_launch_files_load():
    assert Demo.sim_config(PeopleSimParams, "people_sim.yaml") == PeopleSimParams()
    detection_params = Demo.sim_config(ObjectDetectionSimParams, "object_detection_sim.yaml")
    assert detection_params == ObjectDetectionSimParams()
