"""The server's translation of PeopleCount messages into rows (message types, no master)."""
import numpy as np
import pytest
from geometry_msgs.msg import Point

from robot_common.cells import exposure, visible_cells
from robot_common.msg import PeopleCount
from robot_sim import generate_building
from robot_sim.ros_people import sim_stamp
from traffic_gp.errors import TrafficError
from traffic_gp.params import TrafficServerParams
from traffic_gp.ros_traffic import TrafficServer


@pytest.fixture(scope="module")
def server():
    node = TrafficServer(TrafficServerParams(utc_offset_hours=0.0, dwell_time=20.0))
    node._set_map(generate_building(0).grid)
    return node


def message(**fields):
    msg = PeopleCount(robot_id="r7", **fields)
    msg.header.stamp = sim_stamp(48 + 10.5, 0.0)
    return msg


def test_per_cell_counts_become_rows_with_their_exposure(server):
    msg = message(cells=[Point(10.2, 6.6, 0), Point(10.7, 6.6, 0), Point(0.05, 0.05, 0)],
                  seen_fraction=[1.0, 0.5, 1.0], counts=[2, 0, 1], duration=10.0)
    rows = server.to_rows(msg)
    assert len(rows) == 2, "the cell on the outer wall is dropped"
    np.testing.assert_allclose(rows.exposure, [0.25 * 1.5, 0.125 * 1.5])
    # hours since a Monday, counting on across weeks (the time order the fit holds out by)
    np.testing.assert_allclose(np.mod(rows.t, 168.0), 58.5)
    np.testing.assert_allclose(rows.t, msg.header.stamp.to_sec() / 3600.0 + 72.0)
    assert rows.count.tolist() == [2, 0] and list(rows.robot) == ["r7", "r7"]


def test_a_total_count_within_a_radius_becomes_one_row_over_the_seen_area(server):
    rows = server.to_rows(message(robot_position=Point(10.0, 6.5, 0), radius=3.0, total_count=4))
    index, fractions = visible_cells(server.cells, 10.0, 6.5, 3.0)
    assert len(rows) == 1 and rows.count[0] == 4
    assert rows.exposure[0] == pytest.approx(exposure(fractions.sum() * 0.25))


@pytest.mark.parametrize("fields, match", [
    ({"seen_fraction": [1.0, 1.0], "counts": [1]}, "differ in number"),
    ({"seen_fraction": [1.5], "counts": [1]}, "seen_fraction"),
    ({}, "cells or a positive radius"),
])
def test_malformed_messages_are_refused(server, fields, match):
    cells = [Point(10.2, 6.6, 0)] if fields else []
    with pytest.raises(TrafficError, match=match):
        server.to_rows(message(cells=cells, **fields))
