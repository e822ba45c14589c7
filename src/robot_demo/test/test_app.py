"""The demo program without running it: its chapters, its options, the simulator parameters it reads."""
import pytest

from robot_demo.app import CHAPTERS, Demo, parse_args, workspace_root
from robot_sim.params import ObjectDetectionSimParams, PeopleSimParams


def test_the_chapters_run_in_the_documented_order_and_each_has_a_title():
    assert list(CHAPTERS) == ["robot", "data_api", "object_layers", "region_search", "crowd_map",
                              "demonstrations", "fleet", "errands"]
    assert all(module.TITLE and callable(module.run) for module in CHAPTERS.values())


def test_options(tmp_path):
    args = parse_args(["--only", "robot", "crowd_map", "--output", str(tmp_path)])
    assert args.only == ["robot", "crowd_map"] and args.output == tmp_path and not args.keep_running
    with pytest.raises(SystemExit):
        parse_args(["--only", "no_such_chapter"])


def test_composed_launch_files_are_in_the_workspace_launch_folder():
    for name in ("crowd_sim.launch", "object_layers_sim.launch", "demo.launch", "demo.rviz",
                 "errands_sim.launch"):
        assert (workspace_root() / "launch" / name).is_file()
    assert Demo.workspace_launch("crowd_sim.launch").endswith("launch/crowd_sim.launch")


def test_simulator_parameters_come_from_the_files_the_launch_files_load():
    assert Demo.sim_config(PeopleSimParams, "people_sim.yaml") == PeopleSimParams()
    detection_params = Demo.sim_config(ObjectDetectionSimParams, "object_detection_sim.yaml")
    assert detection_params == ObjectDetectionSimParams()


def test_the_fleet_chapter_reads_the_crowd_models_status_and_the_recorders_diagnostics():
    from robot_demo.chapters.fleet import learned_rows

    status = ("model of 120 rows; learned from 2 robots: robot1: 70 rows from 7 messages; "
              "robot2: 50 rows from 5 messages; source central ...")
    assert learned_rows(status) == {"robot1": (70, 7), "robot2": (50, 5)}
    assert learned_rows("model of 0 rows; learned from 0 robots: none yet") == {}


def test_every_wait_of_the_demo_says_what_it_waits_for_and_its_bound(capsys, monkeypatch):
    from robot_demo import waits

    ticks = iter(range(100))
    assert waits.wait_until(lambda: next(ticks) >= 3, 30, "three ticks") is True
    assert capsys.readouterr().out.startswith("    waiting for three ticks (at most 30 s) ... ")
    with pytest.raises(TimeoutError, match="never"):
        waits.wait_until(lambda: False, 0.2, "never")
    assert "waiting for never (at most 0 s) ... not within" in capsys.readouterr().out
    monkeypatch.setenv("DEMO_BOUND_SCALE", "2.5")
    assert waits.bound(60) == 150
    monkeypatch.setenv("DEMO_BOUND_SCALE", "0.1")
    assert waits.bound(60) == 60      # never below the chapter's own bound
