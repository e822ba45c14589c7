"""The crowd-aware planner and its forecast: the route changes with the crowd at the time the
robot gets there, and equals the shortest path when nobody is about."""
import math

import numpy as np
import pytest

from errand_nav.forecast import DensityForecast
from errand_nav.planning import CrowdPlanner, PlannerSettings
from robot_common.errors import MapError
from robot_common.gridplan import CellCosts, NoPathError, cheapest_cells, plan_path
from robot_common.maps import FREE, OCCUPIED, GridMap

RES = 0.25
SETTINGS = PlannerSettings(cell_size=0.25, free_speed=0.6, person_cost=10.0, meet_radius=1.0)
START, GOAL = (1.5, 8.75), (24.5, 8.75)


def carve(cells, x0, y0, x1, y1):
    cells[int(round(y0 / RES)):int(round(y1 / RES)), int(round(x0 / RES)):int(round(x1 / RES))] = FREE


def two_corridors() -> GridMap:
    """26 m x 10 m: lobbies x 0-3 and 23-26 m (y 0-9.5 m), joined by a north corridor (y 8-9.5 m,
    20 m long, on the straight line start-goal) and a south one (y 0-1.5 m): going south adds
    about 2 x 7.25 m of lobby."""
    cells = np.full((int(10 / RES), int(26 / RES)), OCCUPIED, np.int8)
    for box in ((0, 0, 3, 9.5), (23, 0, 26, 9.5), (3, 8, 23, 9.5), (3, 0, 23, 1.5)):
        carve(cells, *box)
    return GridMap(cells, RES)


def north_crowd(grid: GridMap, density: float) -> np.ndarray:
    """A density grid (on the map's cells) with `density` people/m^2 in the north corridor."""
    values = np.zeros(grid.cells.shape)
    values[int(8 / RES):int(9.5 / RES), int(3 / RES):int(23 / RES)] = density
    return values


def forecast_of(grid, times, levels):
    return DensityForecast(grid.origin[:2], grid.resolution, times,
                           np.stack([north_crowd(grid, level) for level in levels]))


def goes_north(path) -> bool:
    return path.points[:, 1].min() > 7.0


def test_the_long_empty_corridor_is_taken_in_the_rush_and_the_short_one_when_quiet():
    grid = two_corridors()
    # 1 person/m^2 in the north corridor until t = 1000 s, nobody from 1001 s on. North in the
    # rush: 20 m x 2 m x 1 = 40 people met (400 s at 10 s each); south: ~15 m more at 0.6 m/s.
    forecast = forecast_of(grid, [0.0, 1000.0, 1001.0, 5000.0], [1.0, 1.0, 0.0, 0.0])
    planner = CrowdPlanner(grid, SETTINGS)
    rush, quiet = planner.plan(START, GOAL, 100.0, forecast), planner.plan(START, GOAL, 2000.0, forecast)
    assert not goes_north(rush) and rush.points[:, 1].min() < 1.5
    assert goes_north(quiet)
    assert quiet.length < 24.0 < 34.0 < rush.length
    assert rush.people_met == pytest.approx(0.0) and quiet.people_met == pytest.approx(0.0)


def test_without_a_crowd_the_plan_is_the_shortest_path_at_the_free_speed():
    grid = two_corridors()
    path = CrowdPlanner(grid, SETTINGS).plan(START, GOAL, 50.0, DensityForecast.quiet(grid))
    shortest = plan_path(grid, START, GOAL, clearance=SETTINGS.clearance, comfort=SETTINGS.comfort,
                         wall_cost=SETTINGS.wall_cost, cell_size=SETTINGS.cell_size)
    np.testing.assert_allclose(path.points, shortest)
    assert path.duration == pytest.approx(path.length / 0.6)
    assert path.times[0] == 50.0 and path.times[-1] == pytest.approx(50.0 + path.length / 0.6)
    assert np.all(np.diff(path.times) >= 0)
    near = CrowdPlanner(grid, SETTINGS).plan(START, (1.55, 8.8), 0.0, DensityForecast.quiet(grid))
    assert near.points.tolist() == [list(START), [1.55, 8.8]]          # both in one cell


def test_a_corridor_crowded_only_by_the_time_the_robot_gets_there_is_avoided():
    grid = two_corridors()
    # nobody at t = 0 s, 1 person/m^2 from t = 10 s: the robot would enter the north corridor
    # after ~2.5 m (4 s) and leave it ~37 s later, meeting the crowd on most of its 20 m
    later = forecast_of(grid, [0.0, 10.0], [0.0, 1.0])
    now_only = forecast_of(grid, [0.0], [0.0])
    planner = CrowdPlanner(grid, SETTINGS)
    assert goes_north(planner.plan(START, GOAL, 0.0, now_only))
    assert not goes_north(planner.plan(START, GOAL, 0.0, later))
    # one crowded now that clears (from 3 s) before the robot gets there (~4 s) is taken
    clearing = forecast_of(grid, [0.0, 3.0], [1.0, 0.0])
    assert goes_north(planner.plan(START, GOAL, 0.0, clearing))
    # with a look-ahead of 0.1 s the forecast is held at 0.01 person/m^2 (0.4 people, 4 s)
    short_look = CrowdPlanner(grid, PlannerSettings(cell_size=0.25, look_ahead=0.1))
    assert goes_north(short_look.plan(START, GOAL, 0.0, later))


def test_evaluate_counts_the_people_in_the_swept_band_and_slows_in_the_crowd():
    cells = np.full((80, 80), FREE, np.int8)                   # a 20 m x 20 m hall
    grid = GridMap(cells, RES)
    forecast = DensityForecast((0.0, 0.0), 0.5, [0.0], np.ones((1, 40, 40)))
    path = CrowdPlanner(grid, SETTINGS).evaluate([(5.0, 10.0), (15.0, 10.0)], 7.0, forecast)
    # 10 m x 2 x 1.0 m x 1 person/m^2 = 20 people; Weidmann at 1/m^2:
    # 0.6 x (1 - exp(-1.913 x (1 - 1/5.4))) = 0.6 x (1 - exp(-1.55874)) = 0.6 x 0.78960 = 0.47376 m/s
    assert path.length == pytest.approx(10.0)
    assert path.people_met == pytest.approx(20.0)
    assert path.duration == pytest.approx(10.0 / 0.47376, rel=1e-4)
    assert path.cost == pytest.approx(10.0 / 0.47376 + 10.0 * 20.0, rel=1e-4)
    assert path.times.tolist() == pytest.approx([7.0, 7.0 + 10.0 / 0.47376], rel=1e-4)


def test_an_unreachable_goal_and_a_goal_in_a_wall_are_refused():
    grid = two_corridors()
    planner = CrowdPlanner(grid, SETTINGS)
    with pytest.raises(NoPathError, match="goal"):
        planner.plan(START, (13.0, 5.0), 0.0, DensityForecast.quiet(grid))    # inside the wall
    grid.cells[:, int(10 / RES):int(11 / RES)] = OCCUPIED                     # both corridors cut
    with pytest.raises(NoPathError, match="no free path"):
        CrowdPlanner(grid, SETTINGS).plan(START, GOAL, 0.0, DensityForecast.quiet(grid))


def test_the_forecast_is_linear_between_its_times_held_beyond_and_zero_off_the_grid():
    grids = np.zeros((2, 3, 4))
    grids[0, 0, 1], grids[1, 0, 1] = 1.0, 3.0                  # row 0 is the bottom row
    forecast = DensityForecast((-1.0, 2.0), 0.5, [10.0, 20.0], grids)
    assert forecast.at(15.0)[0, 1] == pytest.approx(2.0)
    assert forecast.at(0.0)[0, 1] == 1.0 and forecast.at(99.0)[0, 1] == 3.0
    # (-0.25, 2.1) lies in column 1, row 0; (5, 5) is off the 2 m x 1.5 m grid
    assert forecast.density_at(np.array([[-0.25, 2.1], [5.0, 5.0]]), 12.5).tolist() == \
        pytest.approx([1.5, 0.0])
    with pytest.raises(MapError, match="increase"):
        DensityForecast((0, 0), 0.5, [2.0, 1.0], grids)
    with pytest.raises(MapError, match="negative"):
        DensityForecast((0, 0), 0.5, [1.0, 2.0], -grids)
    assert not math.isnan(DensityForecast.quiet(GridMap(np.zeros((2, 2)), 0.1)).at(5.0).sum())


def test_a_door_off_the_search_cells_is_passed_with_the_clearance_measured_on_the_map():
    # two 3.8 m x 4.8 m rooms (0.05 m map cells) joined by a 0.8 m door at y 2.15-2.95 m in a
    # 0.2 m wall: on 0.25 m search cells no whole cell row lies in the door with a free cell on
    # each side, but the door's middle is 0.4 m from its posts: the robot fits with 0.3 m.
    cells = np.full((100, 160), OCCUPIED, np.int8)
    cells[2:98, 2:78] = FREE
    cells[2:98, 82:158] = FREE
    cells[43:59, 78:82] = FREE
    grid = GridMap(cells, 0.05)
    with pytest.raises(NoPathError, match="no free path"):
        plan_path(grid, (1.0, 1.0), (7.0, 1.0), clearance=0.3, cell_size=0.25)
    path = CrowdPlanner(grid, SETTINGS).plan((1.0, 1.0), (7.0, 1.0), 0.0, DensityForecast.quiet(grid))
    in_door = np.abs(path.points[:, 0] - 4.0) < 0.15              # centres 3.875 and 4.125 m
    assert in_door.any() and np.all(np.abs(path.points[in_door, 1] - 2.55) <= 0.4 - 0.3 + 1e-9)


def test_people_met_are_counted_over_the_band_whatever_side_of_a_corridor_the_path_takes():
    grid = two_corridors()
    forecast = forecast_of(grid, [0.0], [1.0])
    planner = CrowdPlanner(grid, SETTINGS)
    # the square around a point of the 1.5 m corridor (rows 32-37 of 0.25 m) spans 9 rows
    # (2.25 m): 6 of them hold 1 person/m^2, so 2 m x 6/9 = 1.333 people per metre of path
    for y in (8.3, 8.75, 9.2):               # bottom row 33 (rows 29-37), 35 (31-39), 36 (32-40)
        path = planner.evaluate([(5.0, y), (15.0, y)], 0.0, forecast)
        assert path.people_met == pytest.approx(10.0 * 2.0 * 6.0 / 9.0)


def _interpolated(layers, stamps, clock, row, col):
    """A cell's value at `clock`: linear between stamps, held beyond (the slow way)."""
    return float(np.interp(clock, stamps, layers[:, row, col]))


def test_the_time_dependent_search_matches_a_label_correcting_reference_when_cost_is_time():
    # cost = pace (the clock itself), changing slower than the clock (FIFO): the earliest
    # arrival is what repeating every move's relaxation until nothing changes gives
    rng = np.random.default_rng(3)
    stamps = [0.0, 5.0, 10.0]
    pace = rng.uniform(1.0, 3.0, (3, 6, 7))
    pace[:, 1:5, 3] = np.inf                                  # a wall with gaps at rows 0, 5
    costs = CellCosts(pace, np.where(np.isfinite(pace), pace, 0.0), stamps)
    cells, clocks = cheapest_cells(costs, (2, 0), (3, 6), 0.0)
    arrival = np.full((6, 7), np.inf)
    arrival[2, 0] = 0.0
    changed = True
    while changed:
        changed = False
        for (row, col), now in np.ndenumerate(arrival):
            if not np.isfinite(now):
                continue
            for d_row, d_col in [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b]:
                r, c = row + d_row, col + d_col
                if not (0 <= r < 6 and 0 <= c < 7 and np.isfinite(pace[0, r, c])):
                    continue
                step = math.hypot(d_row, d_col) * 0.5 * (
                    _interpolated(pace, stamps, now, row, col) + _interpolated(pace, stamps, now, r, c))
                if now + step < arrival[r, c] - 1e-12:
                    arrival[r, c], changed = now + step, True
    assert cells[0] == (2, 0) and cells[-1] == (3, 6)
    assert clocks[-1] == pytest.approx(arrival[3, 6])
