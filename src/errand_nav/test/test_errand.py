"""An errand's bookkeeping (arrival, progress, blockage, forecast looks), the map with what the
laser saw, and the choice of a place from region_search's answer; no ROS."""
import math

import numpy as np
import pytest

from errand_nav.errand import (
    Errand,
    ErrandRules,
    at_hour_of_week,
    nearest_clear,
    remaining_path,
    with_obstacles,
)
from errand_nav.places import choose_place
from robot_common.maps import FREE, OCCUPIED, GridMap

RULES = ErrandRules(goal_tolerance=0.3, progress_step=0.3, blocked_after=10.0,
                    replan_period=30.0, max_replans=2)
PATH = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0]])   # 15 m with a corner


def errand():
    job = Errand((10.0, 5.0), RULES)
    job.follow(PATH, now=0.0)
    return job


def test_arrival_within_the_tolerance_only():
    job = errand()
    assert job.check((10.0, 4.6), 1.0).action == "go"         # 0.4 m away
    assert job.check((10.1, 4.8), 2.0).action == "arrived"     # 0.22 m away


def test_remaining_length_is_measured_along_the_path():
    job = errand()
    assert job.remaining((0.0, 0.0)) == pytest.approx(15.0)
    assert job.remaining((5.0, 0.4)) == pytest.approx(10.0)    # beside the first leg
    assert job.remaining((10.0, 2.0)) == pytest.approx(3.0)


def test_held_up_longer_than_the_bound_is_blocked_and_progress_resets_the_clock():
    job = errand()
    assert job.check((1.0, 0.0), 0.0).action == "go"
    assert job.check((1.1, 0.0), 9.0).action == "go"           # 0.1 m: not progress
    assert job.check((1.2, 0.0), 10.5).action == "blocked"     # 10.5 s without 0.3 m
    job.follow(PATH, now=10.5)                                 # a new path restarts the clock
    assert job.check((1.2, 0.0), 12.0).action == "go"
    assert job.check((2.0, 0.0), 21.0).action == "go"          # 0.8 m on at 21 s
    assert job.check((2.0, 0.0), 30.0).action == "go"          # 9 s since
    assert job.check((2.0, 0.0), 31.5).action == "blocked"


def test_what_the_laser_showed_while_held_counts_as_in_the_way_and_progress_forgets_it():
    job = errand()
    job.check((1.0, 0.0), 0.0)
    job.sighted(np.array([[3.0, 0.5], [7.0, 0.0]]))            # seen, then the robot got on
    assert job.check((2.0, 0.0), 2.0).action == "go"
    for look in range(3):                                       # held: a cart, seen 3 times
        job.sighted(np.array([[2.6, 0.0], [2.61, 0.01]]) + 0.01 * look)
    job.sighted(np.array([[2.6, 0.8]]))                         # someone walking past
    job.sighted(np.array([[2.6, 1.2]]))
    job.sighted(np.zeros((0, 2)))                               # turned away from the cart
    seen = job.saw_blocking(np.array([[2.6, -0.3]]))            # what it sees now counts anyway
    assert sorted(map(tuple, seen.round(2))) == [(2.6, -0.3), (2.6, 0.0), (2.63, 0.03)]
    assert len(job.saw_blocking(np.zeros((0, 2)))) == 3         # kept for the errand, once


def test_kept_obstacles_a_newer_scan_sees_past_are_forgotten_and_the_rest_kept():
    job = errand()
    for _ in range(3):                                       # a group standing in the way
        job.sighted(np.array([[2.6, 0.0], [2.6, 0.3], [5.0, 1.0]]))
    assert len(job.saw_blocking(np.zeros((0, 2)))) == 3
    forgotten = job.seen_clear(lambda points: points[:, 0] < 3.0)    # they left; not the cart
    assert forgotten == 2 and job.obstacles.tolist() == [[5.0, 1.0]]
    assert job.seen_clear(lambda points: np.zeros(len(points), bool)) == 0
    assert job.saw_blocking(np.zeros((0, 2))).tolist() == [[5.0, 1.0]]


def test_a_forecast_look_comes_every_period_while_driving():
    job = errand()
    for t in range(0, 30, 3):
        assert job.check((0.3 * t, 0.0), float(t)).action == "go"
    verdict = job.check((9.0, 0.0), 30.0)
    assert verdict.action == "forecast"


def test_remaining_path_starts_at_the_robot_and_keeps_what_is_ahead():
    ahead = remaining_path(PATH, (10.2, 0.6))             # round the corner
    assert ahead.tolist() == [[10.2, 0.6], [10.0, 5.0]]
    ahead = remaining_path(PATH, (9.4, 0.1))              # before the corner: it is kept
    assert ahead.tolist() == [[9.4, 0.1], [10.0, 0.0], [10.0, 5.0]]
    assert remaining_path(PATH, (10.1, 5.2)).tolist() == [[10.1, 5.2], [10.0, 5.0]]   # at the end


def test_obstacles_are_marked_round_the_points_but_not_on_the_robot():
    cells = np.full((40, 40), FREE, dtype=np.int8)
    grid = GridMap(cells, 0.1)
    marked = with_obstacles(grid, np.array([[2.0, 2.0], [1.0, 1.0]]), radius=0.3,
                            keep_clear=(1.0, 1.0), keep_radius=0.25)
    assert marked.cells[20, 20] == OCCUPIED and marked.cells[20, 23] == OCCUPIED
    assert marked.cells[20, 24] == FREE                        # 0.4 m off: outside the disc
    assert marked.cells[10, 10] == FREE                        # the robot's own spot stays free
    assert (grid.cells == FREE).all()                          # the map itself is untouched


def answer(**changes):
    fields = dict(success=True, message="ok", matched=True, labels=["print room", "library"],
                  scores=[0.9, 0.4], poses=[(3.0, 4.0, 0.5), (8.0, 1.0, 0.0)], confidence=0.93)
    fields.update(changes)
    return fields


def test_a_sure_answer_is_a_goal_at_the_first_place():
    choice = choose_place("where can I print?", **answer())
    assert choice.sure and choice.label == "print room" and choice.pose == (3.0, 4.0, 0.5)
    assert choice.candidates == ["print room", "library"]


def test_not_sure_answers_and_no_match_send_nothing_and_name_the_candidates():
    unsure = choose_place("somewhere quiet", **answer(message="not sure (confidence 0.41, below "
                                                              "0.60): best guess print room",
                                                      confidence=0.41))
    assert not unsure.sure and "print room, library" in unsure.message
    none = choose_place("a swimming pool", **answer(matched=False, labels=[], scores=[], poses=[],
                                                    message="no labelled place matches"))
    assert not none.sure and none.message.startswith("no labelled place")
    failed = choose_place("x", **answer(success=False, message="no embedding service"))
    assert not failed.sure and "no embedding service" in failed.message


def test_the_servers_own_confidence_floor_applies_only_when_set():
    assert choose_place("p", **answer(confidence=0.7)).sure
    stricter = choose_place("p", **answer(confidence=0.7), min_confidence=0.8)
    assert not stricter.sure and "0.80" in stricter.message
    assert choose_place("p", **answer(confidence=math.nan), min_confidence=0.8).sure




def test_an_end_where_the_robot_does_not_fit_moves_to_the_nearest_clear_spot():
    from robot_common.gridplan import SearchGrid
    cells = np.full((40, 40), FREE, dtype=np.int8)
    cells[:, 30:] = OCCUPIED                                   # a wall from x = 3.0 m
    search = SearchGrid(GridMap(cells, 0.1), clearance=0.3, cell_size=0.1)
    assert nearest_clear(search, (1.0, 2.0), 0.6) == (1.0, 2.0)
    x, y = nearest_clear(search, (2.9, 2.02), 0.6)             # 0.1 m from the wall
    # the nearest cell whose centre is 3 cells (0.3 m, centre to centre) from the wall's first
    assert x == pytest.approx(2.75) and y == pytest.approx(2.05)
    assert nearest_clear(search, (3.5, 2.0), 0.6) == (3.5, 2.0)    # in the wall: none near


def test_an_hour_of_the_week_is_counted_from_monday_midnight_utc():
    import calendar
    monday = calendar.timegm((2026, 11, 23, 0, 0, 0))          # a Monday, 00:00 UTC
    wednesday = calendar.timegm((2026, 11, 25, 17, 5, 0))
    sunday = calendar.timegm((2026, 11, 29, 23, 59, 0))
    assert at_hour_of_week(wednesday, 0.0) == monday
    assert at_hour_of_week(sunday, 58.5) == monday + 58.5 * 3600.0   # Wednesday 10:30
    assert at_hour_of_week(monday, 1.0) == monday + 3600.0     # Monday 00:00 is its own week
