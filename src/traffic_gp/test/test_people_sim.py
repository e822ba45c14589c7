"""The people simulator (robot_sim.people): time, true rates, visibility, counts, derived halls."""
import datetime

import numpy as np
import pytest

from robot_common.cells import CellGrid, exposure, hours_of_week, visible_cells
from robot_common.errors import MapError
from robot_common.maps import FREE, OCCUPIED, GridMap
from robot_sim import SimError, generate_building
from robot_sim.people import HallLayout, PeopleSimulator, building_layout, derive_halls

WED = 48.0


def unix(*args) -> float:
    return datetime.datetime(*args, tzinfo=datetime.timezone.utc).timestamp()


def test_hours_of_week_counts_from_monday_midnight():
    assert hours_of_week(unix(2024, 1, 1, 0, 0), 0.0) == pytest.approx(0.0)      # a Monday
    assert hours_of_week(unix(2024, 1, 3, 10, 50), 0.0) == pytest.approx(58.0 + 50 / 60)
    assert hours_of_week(unix(2024, 1, 7, 23, 0), 0.0) == pytest.approx(167.0)   # Sunday night
    assert hours_of_week(unix(2024, 1, 3, 10, 50), 2.0) == pytest.approx(60.0 + 50 / 60)


@pytest.fixture(scope="module")
def sim():
    return PeopleSimulator.from_building(generate_building(0), 0.5, seed=3)


def test_main_hall_busier_than_back_hall_and_rooms(sim):
    main = np.nonzero(sim.layout.main)[0]
    back = np.nonzero((sim.layout.hall >= 0) & ~sim.layout.main)[0]
    rooms = np.nonzero(sim.layout.hall < 0)[0]
    density = sim.density(WED + 14.5)[0]
    assert density[main].mean() > 2.5 * density[back].mean() > 2.5 * density[rooms].mean() > 0


def test_rush_in_the_minutes_before_class_and_not_at_night_or_weekends(sim):
    cell = np.nonzero(sim.layout.main)[0][10]
    before_class, mid_class = sim.density(WED + 10 + 53 / 60, [cell])[0, 0], \
        sim.density(WED + 10.5, [cell])[0, 0]
    assert before_class > 2.5 * mid_class
    assert sim.density(WED + 10 + 50 / 60, [cell])[0, 0] > 2.0 * mid_class   # 10:50 is busy
    assert sim.density(WED + 1.0, [cell])[0, 0] < 0.1 * mid_class             # 1:00 is quiet
    saturday = 5 * 24.0
    assert sim.rush_level(saturday + 10 + 53 / 60) == 0.0
    assert sim.density(saturday + 14.5, [cell])[0, 0] < 0.5 * sim.density(WED + 14.5, [cell])[0, 0]


def test_the_week_repeats(sim):
    np.testing.assert_allclose(sim.density(WED + 9.9), sim.density(WED + 9.9 + 168.0))


def two_rooms() -> GridMap:
    """Two 4 x 4 m rooms side by side, a solid wall between them, 0.1 m map cells."""
    cells = np.full((42, 84), OCCUPIED, dtype=np.int8)
    cells[1:41, 1:41] = FREE
    cells[1:41, 43:83] = FREE
    return GridMap(cells, 0.1)


def test_visibility_stops_at_walls_and_at_the_radius():
    cells = CellGrid.from_map(two_rooms(), 0.5)
    index, fractions = visible_cells(cells, 2.0, 2.0, radius=1.2)
    xs, ys = cells.x[index], cells.y[index]
    assert np.all(xs < 4.1), "cells behind the wall must not be seen"
    centre = cells.index_at(np.array([2.2]), np.array([2.2]))[0]
    assert fractions[list(index).index(centre)] == 1.0
    assert np.all(np.hypot(xs - 2.0, ys - 2.0) <= 1.2 + 0.75)
    assert np.any((fractions > 0) & (fractions < 1)), "cells cut by the view's edge are partly seen"
    wide_index, _ = visible_cells(cells, 2.0, 2.0, radius=20.0)
    assert np.all(cells.x[wide_index] < 4.1) and wide_index.size > index.size


def test_views_list_seen_cells_with_zero_counts_and_never_unseen_cells():
    grid = two_rooms()
    cells = CellGrid.from_map(grid, 0.5)
    layout = HallLayout(["left"], np.where(cells.x < 4.2, 1.0, 0.0), np.where(cells.x < 4.2, 0, -1),
                        cells.x < 4.2)
    sim = PeopleSimulator(cells, layout, peak_density=0.05, seed=1)
    views = sim.observe(300, robots=2, start=WED + 13, hours=1.0, radius=2.0, hall_share=1.0)
    assert {v.robot_id for v in views} == {"robot_0", "robot_1"}
    seen_right = [v for v in views if np.any(cells.x[v.cells] > 4.2)]
    assert not seen_right
    zeros = sum(int(np.sum(v.counts == 0)) for v in views)
    assert zeros > 0 and all(len(v.cells) == len(v.counts) == len(v.fractions) for v in views)


def test_counts_are_poisson_with_the_true_mean_times_exposure():
    cells = CellGrid.from_map(two_rooms(), 0.5)
    layout = HallLayout(["all"], np.ones(cells.n_cells), np.zeros(cells.n_cells, int),
                        np.ones(cells.n_cells, bool))
    sim = PeopleSimulator(cells, layout, peak_density=0.8, rush_gain=0.0, seed=2)
    views = sim.observe(400, start=WED + 14.0, hours=0.01, radius=3.0, duration=10.0)
    counts = np.concatenate([v.counts for v in views])
    expo = np.concatenate([exposure(v.fractions * cells.cell_area, 10.0) for v in views])
    truth = sim.density(WED + 14.0)[0, 0]
    assert counts.sum() / expo.sum() == pytest.approx(truth, rel=0.05)
    # Poisson: variance equals mean for full-cell snapshots of the same exposure
    full = np.concatenate([v.fractions == 1.0 for v in views])
    assert counts[full].var() == pytest.approx(counts[full].mean(), rel=0.1)


def test_derived_halls_find_the_generated_main_hall():
    building = generate_building(0)
    cells = CellGrid.from_map(building.grid, 0.5)
    truth = building_layout(building, cells)
    derived = derive_halls(building.grid, cells)
    true_main, found_main = truth.main, derived.main
    overlap = np.sum(true_main & found_main) / np.sum(true_main | found_main)
    assert overlap > 0.8
    rooms = truth.hall < 0
    assert np.mean(derived.hall[rooms] >= 0) < 0.15, "rooms are not corridors"
    back = truth.hall == 1
    assert np.mean(derived.hall[back] >= 0) > 0.6 and np.mean(derived.main[back]) < 0.15


def test_bad_requests_and_maps_raise_clear_errors(sim):
    with pytest.raises(SimError, match="bad observation request"):
        sim.observe(10, robots=0)
    with pytest.raises(MapError, match="cell_size"):      # CellGrid is robot_common's now
        CellGrid.from_map(two_rooms(), 0.0)
    with pytest.raises(MapError, match="no free cell"):
        CellGrid.from_map(GridMap(np.full((5, 5), OCCUPIED, np.int8), 0.1), 0.2)


def test_cells_mask_walls_and_index_points(sim):
    cells = sim.cells
    assert cells.cell_size == pytest.approx(0.5)
    assert cells.index_at(np.array([0.05]), np.array([0.05]))[0] == -1     # outer wall
    inside = cells.index_at(np.array([cells.x[7]]), np.array([cells.y[7]]))[0]
    assert inside == 7
