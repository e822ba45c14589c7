"""Observation rows: from robots' views, validation, compression, one-count views."""
import numpy as np
import pytest

from robot_common.cells import CellGrid, View
from robot_sim import generate_building
from traffic_gp.errors import ObservationError
from traffic_gp.observations import Observations, aggregate_view


@pytest.fixture(scope="module")
def cells():
    return CellGrid.from_map(generate_building(0).grid, 0.5)


def test_rows_per_seen_cell_with_exposure_from_fraction_and_duration(cells):
    view = View("r1", 50.0, 3.0, 6.0, 10.0, np.array([4, 9]), np.array([1.0, 0.5]), np.array([2, 0]))
    rows = Observations.from_views(cells, [view], dwell_time=20.0)
    np.testing.assert_allclose(rows.x, cells.x[[4, 9]])
    # 0.25 m^2 cells; a 10 s watch sees people for 1 + 10/20 = 1.5 times as long as a snapshot
    np.testing.assert_allclose(rows.exposure, [0.25 * 1.5, 0.125 * 1.5])
    assert rows.count.tolist() == [2, 0] and rows.t.tolist() == [50.0, 50.0]
    assert list(rows.robot) == ["r1", "r1"]


@pytest.mark.parametrize("field, value, match", [
    ("count", [-1.0], "non-negative integers"),
    ("count", [0.5], "non-negative integers"),
    ("exposure", [0.0], "exposure must be positive"),
    ("t", [float("nan")], "non-finite"),
])
def test_bad_rows_are_refused_with_the_offending_values(field, value, match):
    values = {"x": [1.0], "y": [1.0], "t": [1.0], "exposure": [0.25], "count": [1.0]}
    values[field] = value
    with pytest.raises(ObservationError, match=match):
        Observations(**values)


def test_fields_of_different_length_are_refused():
    with pytest.raises(ObservationError, match="differ in length"):
        Observations([1.0, 2.0], [1.0], [1.0], [0.25], [1.0])


def test_bad_cell_indices_are_refused(cells):
    view = View("r", 1.0, 0.0, 0.0, 0.0, np.array([cells.n_cells]), np.array([1.0]), np.array([1]))
    with pytest.raises(ObservationError, match="cell indices"):
        Observations.from_views(cells, [view])


def test_compress_keeps_totals_and_merges_same_place_and_bin():
    rows = Observations([1, 1, 1, 2], [0, 0, 0, 0], [10.01, 10.02, 34.015, 10.0],
                        [0.25, 0.1, 0.25, 0.25], [1, 0, 2, 3])
    merged = rows.compress(2 / 60.0, period=24.0)        # 34.015 h is 10:00.9 the next day
    assert len(merged) == 2
    assert merged.count.sum() == 6 and merged.exposure.sum() == pytest.approx(0.85)
    first = merged.x == 1
    assert merged.count[first][0] == 3 and merged.exposure[first][0] == pytest.approx(0.6)


def test_a_single_count_view_gives_one_row_at_the_centre_of_what_was_seen(cells):
    rows = aggregate_view(cells, [4, 5], [1.0, 1.0], 3, 10.0, duration=0.0, robot="r")
    assert len(rows) == 1 and rows.count[0] == 3
    assert rows.exposure[0] == pytest.approx(0.5)
    assert rows.x[0] == pytest.approx((cells.x[4] + cells.x[5]) / 2)
    with pytest.raises(ObservationError, match="at least one cell"):
        aggregate_view(cells, [], [], 0, 10.0)
