"""traffic_gp.sim's map specs: `generated:SEED`, `generated-loop:SEED` or a map file."""
import pytest

from robot_common.errors import ConfigError
from traffic_gp.sim.cli import main
from traffic_gp.sim.evaluation import generated_spec, simulator_for


def test_generated_specs_name_the_layout_and_the_seed():
    assert generated_spec("generated:4") == ("hall", 4)
    assert generated_spec("generated-loop:7") == ("loop", 7)
    assert generated_spec("generated") == ("hall", 0)
    assert generated_spec("maps/floor.yaml") is None
    with pytest.raises(ConfigError, match="bad seed 'x'"):
        generated_spec("generated-loop:x")


def test_the_loop_spec_gives_a_people_model_with_the_loop_s_corridors():
    hall = simulator_for("generated:0", 0.5, seed=1)
    loop = simulator_for("generated-loop:0", 0.5, seed=1)
    assert hall.layout.names == ["main_hall", "back_hall"]
    assert loop.layout.names == ["main_hall", "back_hall", "west_corridor", "north_corridor"]
    assert loop.cells.grid.origin[0] < 0 < loop.cells.n_cells - hall.cells.n_cells


def test_the_command_line_refuses_a_bad_map_spec_in_one_line(tmp_path, capsys):
    status = main(["train", "--map", "generated-loop:x", "--views", "10", "--out",
                   str(tmp_path / "crowd.npz")])
    assert status == 1 and "ERROR: bad seed 'x'" in capsys.readouterr().err
    assert not (tmp_path / "crowd.npz").exists()
