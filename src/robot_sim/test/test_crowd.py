"""People as individuals: the crowd's counts match the people model, the laser sees them, the
tracker misses and invents tracks at its rates."""
import math

import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_common.maps import OCCUPIED, GridMap
from robot_sim.crowd import Crowd, Tracker, disc_ranges
from robot_sim.errors import SimError
from robot_sim.people import HallLayout, PeopleSimulator


def open_room(peak_density=2.0, seed=0):
    """A 6 m x 3 m room (0.1 m map, one-pixel walls): 40 free 0.5 m cells, every one a main hall
    cell of busy level 1, so at hour 14 of a Monday the density is peak x day level."""
    cells = np.zeros((30, 60), dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    grid = CellGrid.from_map(GridMap(cells, 0.1), 0.5)
    n = grid.n_cells
    layout = HallLayout(["hall"], np.ones(n), np.zeros(n, int), np.ones(n, bool))
    return PeopleSimulator(grid, layout, peak_density=peak_density, rush_gain=0.0, seed=seed)


def test_a_ray_stops_at_the_first_disc_in_its_way():
    centres = np.array([[2.0, 0.0], [4.0, 0.0]])
    ranges = disc_ranges(0.0, 0.0, np.array([0.0, math.pi / 2, math.pi]), centres, 0.5)
    # along +x the disc at 2 m is entered at 1.5 m; nothing along +y or -x
    assert ranges[0] == pytest.approx(1.5) and np.isinf(ranges[1:]).all()


def test_the_crowd_holds_the_people_model_s_expected_count_over_time():
    sim = open_room()
    crowd = Crowd(sim, seed=3)
    hours = 14.0
    expected = sim.expected_count(hours)[0].sum()       # the model's people in the room
    sizes, names = [], set()
    for step in range(400):                             # 400 s in 1 s steps, 20 dwell times
        crowd.advance(float(step), hours)
        sizes.append(crowd.names.size)
        names.update(crowd.names.tolist())
    assert np.mean(sizes) == pytest.approx(expected, rel=0.1)
    # different people in 400 s: those at the start plus arrivals, expected x (1 + 400 / 20)
    assert len(names) == pytest.approx(expected * 21, rel=0.1)


def test_after_a_long_gap_the_crowd_is_the_stationary_one_again():
    """A robot stopping here now and again an hour later meets the model's crowd both times, not
    an hour's arrivals piled up."""
    sim = open_room()
    crowd = Crowd(sim, seed=4)
    hours = 14.0
    expected = sim.expected_count(hours)[0].sum()
    sizes = []
    for stop in range(200):                              # a stop every hour, same time of day
        crowd.advance(3600.0 * stop, hours)
        sizes.append(crowd.names.size)
    # the mean of 200 Poisson(expected) draws: within 5 standard errors
    assert abs(np.mean(sizes) - expected) < 5 * math.sqrt(expected / len(sizes))


def test_a_perfect_tracker_reports_the_people_the_laser_sees_and_no_one_else():
    sim = open_room()
    crowd = Crowd(sim, seed=1)
    crowd.advance(0.0, 14.0)
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    tracker = Tracker(miss_rate=0.0, false_positive_rate=0.0, noise=0.0)
    ranges, report, truth = tracker.scan(sim.cells.grid, crowd, (3.0, 1.5, 0.0), angles, 10.0)
    assert [p.name for p in report] == [p.name for p in truth] and len(truth) > 0
    assert len(truth) < crowd.names.size           # some are behind others
    assert ranges.max() < 3.5                      # the room's walls bound every beam


def test_the_tracker_misses_and_invents_tracks_at_its_rates():
    sim = open_room()
    crowd = Crowd(sim, seed=2)
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    tracker = Tracker(miss_rate=0.2, false_positive_rate=0.25, false_track_scans=2, seed=4)
    true_reported = false_reported = visible = 0
    for step in range(300):
        crowd.advance(step * 0.1, 14.0)
        _, report, truth = tracker.scan(sim.cells.grid, crowd, (3.0, 1.5, 0.0), angles, 10.0)
        visible += len(truth)
        false_reported += sum(p.name.startswith("false") for p in report)
        true_reported += sum(not p.name.startswith("false") for p in report)
    assert 1 - true_reported / visible == pytest.approx(0.2, abs=0.03)
    assert false_reported / (false_reported + true_reported) == pytest.approx(0.25, abs=0.03)
    with pytest.raises(SimError, match="miss_rate=1"):
        Tracker(miss_rate=1)
