"""teach_hallway's command line: a reward learned from one short simulated drive is written and
loads as reward_controller loads it, with the barrier margin it was checked with; bad floors
get one ERROR line and no file."""
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
