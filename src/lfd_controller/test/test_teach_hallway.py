"""teach_hallway's command line: a reward learned from one short simulated drive is written and
loads as reward_controller loads it, with the barrier margin it was checked with; bad floors
get one ERROR line and no file."""
import math

import pytest
import yaml

from lfd_controller.hallway_features import HallwayFeatures
from lfd_controller.learning import controller_settings, load_reward
from lfd_controller.params import RewardControllerParams
from lfd_controller.sim.teach_hallway import floor_grid, main
from robot_common.maps import GridMap


def test_one_short_drive_gives_a_reward_file_reward_controller_drives_with(tmp_path, capsys):
    out = tmp_path / "hallway.yaml"
    # one 4-6 m drive of the generated floor's first scene (a few CPU-seconds)
    status = main(["--family", "tangent", "--floor", "generated:0", "--demos", "1",
                   "--length", "4", "6", "--out", str(out), "--accept-anyway"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    # progress: the first of at most 3 scenes gave the one demonstration, then the check
    assert "scene 1/3" in captured.err and "demonstration 1/1" in captured.err
    assert "acceptance 1/1" in captured.err
    reward = load_reward(str(out))            # what ros_controller.start does with the file
    assert isinstance(reward.features, HallwayFeatures)      # -> the path mode
    saved = controller_settings(str(out))
    assert set(saved) == {"barrier_margin"}
    config = RewardControllerParams.from_mapping({"reward_file": str(out)})
    driven = config.with_reward_settings(saved).hallway_safety()
    assert driven["barrier_margin"] == saved["barrier_margin"] >= 0.1    # room_margin's floor
    info = yaml.safe_load(out.read_text())["info"]
    assert (info["family"], info["floor"], info["demonstrations"]) == ("tangent", "generated:0", 1)
    assert info["windows"] > 0 and info["learning_seconds"] > 0
    assert isinstance(info["acceptance"]["accepted"], bool)
    assert info["acceptance"]["accepted"] == ("saved_anyway" not in info["acceptance"])


@pytest.mark.parametrize("floor, message", [
    ("generated:x", "integer seed"),
    ("floor.png", "generated:SEED or a map_server .yaml"),
    ("missing.yaml", "cannot load the floor map"),
])
def test_a_bad_floor_is_one_error_line_and_no_file(tmp_path, capsys, floor, message):
    out = tmp_path / "r.yaml"
    assert main(["--family", "tangent", "--floor", floor, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ERROR: ") and message in err[0]
    assert not out.exists()


def test_the_floor_of_a_map_file_is_read(tmp_path):
    (tmp_path / "f.pgm").write_bytes(b"P5\n2 1\n255\n" + bytes([254, 0]))
    (tmp_path / "f.yaml").write_text("image: f.pgm\nresolution: 0.5\norigin: [0, 0, 0]\n"
                                     "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    grid = floor_grid(str(tmp_path / "f.yaml"))
    assert isinstance(grid, GridMap) and grid.resolution == 0.5


def test_giving_way_is_scored_against_who_really_waited_for_the_robot():
    import numpy as np

    from lfd_controller.sim.teach_hallway import WaitsForRobot
    from robot_common.maps import FREE
    from robot_sim.hallway import HallwayScene, Walker
    cells = np.full((40, 100), FREE, dtype=np.int8)
    near = Walker("near", "head-on", np.array([[3.0, 2.0], [0.0, 2.0]]))     # held where they are
    far = Walker("far", "head-on", np.array([[9.0, 2.0], [6.0, 2.0]]))
    scene = HallwayScene(GridMap(cells, 0.1), np.array([[1.0, 2.0], [9.0, 2.0]]),
                         np.array([1.0, 2.0, 0.0, 0.0, 0.0]), [near, far])
    standing, moving = np.array([2.0, 2.0, 0.0, 0.0, 0.0]), np.array([2.0, 2.0, 0.0, 0.5, 0.0])
    waits = WaitsForRobot(scene)
    near.holding = True                   # 1 m away and waiting for the robot
    for t in np.arange(0.0, 5.0, 0.1):    # a 5 s standoff, never given way in
        waits.step(standing, t, False)
    waits.step(moving, 5.0, False)        # drives on past: that wait is over
    waits.step(standing, 5.1, True)       # gives way to them: right
    near.holding, far.holding = False, True
    waits.step(standing, 5.2, True)       # gives way with only someone 7 m off waiting: wrong
    for t in np.arange(5.3, 6.0, 0.1):    # a wait too short to count
        near.holding = True
        waits.step(standing, t, False)
    waits.step(moving, 6.0, False)
    for t in np.arange(6.1, 11.0, 0.1):   # 5 s turning to its path: not held up
        waits.step(standing, t, False, held=False)
    waits.step(moving, 11.0, False)
    facing_away = np.array([2.0, 2.0, math.pi, 0.0, 0.0])
    for t in np.arange(11.1, 16.0, 0.1):  # 5 s held with them behind it: no standoff either
        waits.step(facing_away, t, False)
    assert waits.figures() == {"right": 1, "wrong": 1, "standoffs": 1, "missed": 1}
