"""The people counter's core: cells seen by a scan in the map, occlusion by walls and people,
each tracked person counted once per cell and watch, and the watch's exposure.

The map of every test: 6 m x 3 m at 0.1 m with a one-pixel wall all round; its 0.5 m cells that
hold no wall pixel are the 10 x 4 free cells between x 0.5..5.5 and y 0.5..2.5.
"""
import math

import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_common.maps import OCCUPIED, GridMap
from traffic_gp.counting import Detection, PeopleCounter, Scan
from traffic_gp.errors import TrafficError


def corridor(inner_wall_col=None):
    cells = np.zeros((30, 60), dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    if inner_wall_col is not None:
        cells[:, inner_wall_col] = OCCUPIED
    return CellGrid.from_map(GridMap(cells, 0.1), 0.5)


def full_scan(stamp, x, y, *, ranges=math.inf, beams=720, yaw=0.0, span=2 * math.pi, hits=(),
              radius=0.25):
    """A scan from (x, y); 360 degrees unless `span` says otherwise; no return by default, and
    beams that meet the disc of `radius` round a person of `hits` stop where they enter it."""
    if span >= 2 * math.pi:
        angles = np.linspace(-math.pi, math.pi, beams, endpoint=False)
    else:
        angles = np.linspace(-span / 2, span / 2, beams)
    readings = np.full(beams, ranges, dtype=float)
    for person in hits:
        dx, dy = person.x - x, person.y - y
        for i, angle in enumerate(angles + yaw):
            along = dx * math.cos(angle) + dy * math.sin(angle)     # along the beam
            across = abs(dy * math.cos(angle) - dx * math.sin(angle))
            if along > 0 and across < radius:
                readings[i] = min(readings[i], along - math.sqrt(radius ** 2 - across ** 2))
    return Scan(stamp, (x, y, yaw), angles, readings, 0.05, 10.0)


def cell_at(cells, x, y):
    return int(cells.index_at(np.array([x]), np.array([y]))[0])


def seen_of(watch):
    return dict(zip(watch.cells.tolist(), watch.fractions.tolist()))


def test_an_open_room_is_seen_whole_from_its_middle():
    cells = corridor()
    counter = PeopleCounter(cells, max_range=8.0)
    counter.add(full_scan(0.0, 3.0, 1.5), [])
    watch = counter.flush()
    # all 10 x 4 free cells, every sample point in view; one scan: duration 0, nobody there
    assert len(watch.cells) == 40 == cells.n_cells
    np.testing.assert_allclose(watch.fractions, 1.0)
    assert watch.counts.sum() == 0 and watch.duration == 0.0
    assert (watch.x, watch.y) == (3.0, 1.5)


def test_a_wall_hides_the_cells_behind_it():
    cells = corridor(inner_wall_col=40)       # a wall at x 4.0..4.1: the cells of x 4.0..4.5 are walls
    counter = PeopleCounter(cells)
    counter.add(full_scan(0.0, 2.0, 1.5), [])
    watch = counter.flush()
    xs = cells.x[watch.cells]
    # 7 columns x 4 rows of cells left of the wall are seen, the 2 x 4 right of it are not
    assert len(watch.cells) == 28 and xs.max() == pytest.approx(3.75)
    assert cells.n_cells == 36


def test_a_person_hides_the_cells_in_their_shadow_and_is_counted_in_their_own_cell():
    cells = corridor()
    counter = PeopleCounter(cells, person_radius=0.25, min_detections=1)
    person = Detection("p1", 2.25, 1.25)
    counter.add(full_scan(0.0, 0.75, 1.25, hits=[person]), [person])
    seen = seen_of(counter.flush())
    # 1.5 m ahead, a 0.25 m disc shades beams within asin(0.25 / 1.5) = 9.6 degrees beyond its
    # far side (1.75 m at most): every sample point of the cell at (4.75, 1.25) is 3.8 m away or
    # more and within 2.4 degrees of the line, so it is not seen
    assert cell_at(cells, 4.75, 1.25) not in seen
    # the cell at (4.75, 2.25) lies 11.8 degrees and more off the line: seen whole
    assert seen[cell_at(cells, 4.75, 2.25)] == pytest.approx(1.0)
    # the person's own cell: its points up to the disc's far side are seen; the farthest, at
    # (2.417, 1.417), is 1.675 m away on a beam that leaves the disc 1.693 m out: all 9 are seen
    assert seen[cell_at(cells, 2.25, 1.25)] == pytest.approx(1.0)


def test_a_person_behind_another_is_not_counted():
    cells = corridor()
    counter = PeopleCounter(cells, min_detections=1)
    front, behind = Detection("front", 2.25, 1.25), Detection("behind", 4.25, 1.25)
    counter.add(full_scan(0.0, 0.75, 1.25, hits=[front, behind]), [front, behind])
    watch = counter.flush()
    counts = dict(zip(watch.cells.tolist(), watch.counts.tolist()))
    assert counts[cell_at(cells, 2.25, 1.25)] == 1
    assert cell_at(cells, 4.25, 1.25) not in counts and watch.counts.sum() == 1


def test_nothing_outside_the_field_of_view_is_seen():
    cells = corridor()
    counter = PeopleCounter(cells)
    counter.add(full_scan(0.0, 3.0, 1.5, beams=181, span=math.pi), [Detection("back", 2.25, 1.25)])
    watch = counter.flush()
    # facing +x over -90..90 degrees: the 5 x 4 cells right of x = 3.0, all of each; the person
    # behind the laser is not counted
    assert len(watch.cells) == 20 and cells.x[watch.cells].min() == pytest.approx(3.25)
    np.testing.assert_allclose(watch.fractions, 1.0)
    assert watch.counts.sum() == 0


def test_a_short_reading_bounds_the_view_and_unusable_readings_see_nothing():
    cells = corridor()
    counter = PeopleCounter(cells, person_radius=0.0)
    counter.add(full_scan(0.0, 3.0, 1.5, ranges=1.0), [])
    seen = seen_of(counter.flush())
    # something unmapped 1 m away all round: the cell at (3.25, 1.75) (farthest point 0.59 m) is
    # seen whole, the cell at (4.25, 1.25) (nearest point 1.08 m away) not at all
    assert seen[cell_at(cells, 3.25, 1.75)] == pytest.approx(1.0)
    assert cell_at(cells, 4.25, 1.25) not in seen
    counter.add(full_scan(1.0, 3.0, 1.5, ranges=math.nan), [])
    assert len(counter.flush().cells) == 0


def test_a_robot_standing_still_counts_each_tracked_person_once():
    cells = corridor()
    counter = PeopleCounter(cells, watch=100.0, min_detections=3)
    stay, brief = Detection("stay", 2.25, 1.25), Detection("brief", 4.25, 2.25)
    for step in range(50):                             # 5 s of scans at 10 Hz
        people = [stay] + ([brief] if step < 2 else [])   # "brief": 2 detections, a false track
        people += [Detection("", 3.75, 0.75)] * (2 if step == 7 else 1)
        assert counter.add(full_scan(step * 0.1, 3.0, 1.75), people) is None
    watch = counter.flush()
    counts = dict(zip(watch.cells.tolist(), watch.counts.tolist()))
    assert counts[cell_at(cells, 2.25, 1.25)] == 1          # 50 detections, one person
    assert counts[cell_at(cells, 4.25, 2.25)] == 0          # fewer than 3 detections: not counted
    assert counts[cell_at(cells, 3.75, 0.75)] == 2          # untracked: the most in one scan


def test_a_person_walking_through_three_cells_counts_once_in_each():
    cells = corridor()
    counter = PeopleCounter(cells, min_detections=3, smoothing=0.3, cell_margin=0.1)
    path = [1.25] * 6 + [1.75] * 6 + [2.25] * 6
    for step, x in enumerate(path):
        counter.add(full_scan(step * 0.1, 3.0, 0.75), [Detection("walker", x, 1.75)])
    watch = counter.flush()
    # smoothed x after the step to 1.75: 1.40, 1.505, 1.579, 1.630 (beyond the cell's edge 1.5
    # by more than 0.1: now in the next cell); after the step to 2.25: .., 2.046, 2.107 (beyond 2.1)
    counted = sorted(cells.x[watch.cells[watch.counts > 0]].tolist())
    assert counted == [1.25, 1.75, 2.25] and watch.counts.sum() == 3


def test_a_person_standing_at_a_cell_edge_counts_once_as_the_position_jitters():
    cells = corridor()
    counter = PeopleCounter(cells, min_detections=3, smoothing=0.3, cell_margin=0.1)
    for step in range(40):             # x jitters about the edge at x = 2.0 between cells
        counter.add(full_scan(step * 0.1, 3.0, 0.75),
                    [Detection("still", 1.98 if step % 2 == 0 else 2.03, 1.75)])
    watch = counter.flush()
    # first seen at 1.98 (the cell of x 1.5..2.0); the smoothed x stays within 1.98..2.03, never
    # 0.1 beyond that cell, so the person counts there only
    counted = cells.x[watch.cells[watch.counts > 0]].tolist()
    assert counted == [1.75] and watch.counts.sum() == 1


def test_the_watch_exposure_counts_the_seconds_each_cell_was_seen():
    cells = corridor()
    counter = PeopleCounter(cells, watch=100.0, dwell_time=20.0, max_gap=0.5)
    blocker = Detection("blocker", 2.25, 1.25)
    for step in range(41):                             # scans at t = 0, 0.5, .., 20
        people = [blocker] if step <= 20 else []          # in the way until t = 10
        counter.add(full_scan(step * 0.5, 0.75, 1.25, hits=people), people)
    watch = counter.flush()
    seen = seen_of(watch)
    assert watch.duration == pytest.approx(20.0)
    # seen all the time: first look 1 + 40 scans x 0.5 s / 20 s = 2, over 1 + 20 / 20 = 2
    assert seen[cell_at(cells, 4.75, 2.25)] == pytest.approx(1.0)
    # shaded until t = 10: first look 1 + 20 scans x 0.5 s / 20 s = 1.5, over 2: 0.75
    assert seen[cell_at(cells, 4.75, 1.25)] == pytest.approx(0.75)


def test_watches_end_after_the_watch_seconds_and_when_time_goes_back():
    cells = corridor()
    counter = PeopleCounter(cells, watch=5.0)
    ended = [counter.add(full_scan(float(t), 3.0, 1.5), []) for t in range(13)]
    done = [watch for watch in ended if watch is not None]
    assert [(w.start, w.duration) for w in done] == [(0.0, 4.0), (5.0, 4.0)]
    back = counter.add(full_scan(3.0, 3.0, 1.5), [])    # a bag played again: a new watch
    assert (back.start, back.duration) == (10.0, 2.0)
    assert counter.flush().start == 3.0 and counter.flush() is None


def test_bad_settings_are_refused():
    with pytest.raises(TrafficError, match="watch=0"):
        PeopleCounter(corridor(), watch=0)
    with pytest.raises(TrafficError, match="confirm_time=5.0"):
        PeopleCounter(corridor(), watch=5.0, confirm_time=5.0)


def test_a_tracked_disc_the_laser_reads_past_hides_nothing():
    cells = corridor()
    counter = PeopleCounter(cells, person_radius=0.25)
    ghost = Detection("ghost", 2.25, 1.25)          # tracked, but every beam through it reads on
    counter.add(full_scan(0.0, 0.75, 1.25), [ghost])
    seen = seen_of(counter.flush())
    # the beams through its disc have no return: they saw the cell behind it, 3.75 m along the
    # line and beyond, whole (a person the laser met would hide it: the shadow test above)
    assert seen[cell_at(cells, 4.75, 1.25)] == pytest.approx(1.0)


def test_a_half_hidden_person_is_counted():
    cells = corridor()
    counter = PeopleCounter(cells, person_radius=0.25, min_detections=1)
    front, half_hidden = Detection("front", 2.25, 1.25), Detection("half", 4.25, 1.75)
    counter.add(full_scan(0.0, 0.75, 1.25, hits=[front, half_hidden]), [front, half_hidden])
    watch = counter.flush()
    counts = dict(zip(watch.cells.tolist(), watch.counts.tolist()))
    # seen from (0.75, 1.25): the front disc spans bearings up to asin(0.25 / 1.5) = 9.6
    # degrees; the other's centre is at atan(0.5 / 3.5) = 8.1 degrees (its beam stops at the
    # front disc), its disc spans 8.1 +- asin(0.25 / 3.54) = 4.1..12.2 degrees: the beams of
    # 9.6..12.2 degrees reach it, so it is seen and counted in its cell
    assert counts[cell_at(cells, 2.25, 1.25)] == 1
    assert counts[cell_at(cells, 4.25, 1.75)] == 1


def test_a_people_message_used_for_two_scans_confirms_its_tracks_once():
    cells = corridor()
    counter = PeopleCounter(cells, watch=100.0, min_detections=3)
    person = Detection("slow", 2.25, 1.25)
    for step in range(4):             # a tracker at half the laser's rate: messages at 0 and 0.2 s
        message = (step // 2) * 0.2
        counter.add(full_scan(step * 0.1, 0.75, 1.25, hits=[person]), [person], seen_at=message)
    assert counter.flush().counts.sum() == 0         # two detections, not four
    counter.add(full_scan(0.4, 0.75, 1.25, hits=[person]), [person], seen_at=0.4)
    assert counter.flush().counts.sum() == 1         # the third message confirms the track


def test_a_person_first_seen_at_a_watchs_end_counts_in_it_once_confirmed():
    cells = corridor()
    counter = PeopleCounter(cells, watch=1.0, min_detections=3, confirm_time=0.45)
    late = Detection("late", 2.25, 1.25)
    ended = {}
    for step in range(20):                           # scans at 0, 0.1, .., 1.9 s
        people = [late] if step >= 9 else []         # seen from t = 0.9, the first watch's last
        watch = counter.add(full_scan(step / 10, 0.75, 1.75, hits=people), people)
        if watch is not None:
            ended[step] = watch
    # the first watch (scans 0..0.9 s) ends at the scan of 1.0 s and is returned at the first scan
    # 0.45 s after its last (1.4 s); by then the track has its 3 detections (0.9, 1.0, 1.1 s)
    assert list(ended) == [14]
    first = ended[14]
    assert (first.start, first.duration) == (0.0, pytest.approx(0.9))
    counts = dict(zip(first.cells.tolist(), first.counts.tolist()))
    assert counts[cell_at(cells, 2.25, 1.25)] == 1 and first.counts.sum() == 1
