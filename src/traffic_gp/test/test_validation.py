"""The time-ordered hold-out: the most recent whole days, never random rows (NumPy only)."""
import numpy as np

from traffic_gp.validation import time_split


def hourly(days: int, places: int = 3) -> np.ndarray:
    """Times of hourly rows at `places` places over `days` days, shuffled (row order must not
    matter, only the times)."""
    t = np.repeat(np.arange(days * 24) + 0.5, places)
    return np.random.default_rng(0).permutation(t)


def test_the_last_whole_days_are_held_out_and_every_earlier_row_fits():
    t = hourly(10)
    split = time_split(t, 0.2)
    assert split.days == 10 and split.held_out_days == 2 and split.cut_hours == 8 * 24.0
    assert np.all(t[split.held_out] >= 8 * 24.0) and np.all(t[split.fit] < 8 * 24.0)
    assert len(split.held_out) == 2 * 24 * 3 and len(split.fit) == 8 * 24 * 3
    assert sorted(np.concatenate([split.fit, split.held_out]).tolist()) == list(range(t.size))
    assert "2 of 10 days" in split.describe()


def test_from_four_weeks_on_the_last_week_is_held_out():
    split = time_split(hourly(30), 0.2)
    assert split.held_out_days == 7 and split.cut_hours == 23 * 24.0


def test_at_least_one_day_and_never_every_day():
    assert time_split(hourly(3), 0.1).held_out_days == 1      # round(0.3) = 0 -> 1
    assert time_split(hourly(2), 0.9).held_out_days == 1      # one day must stay to fit on


def test_days_are_counted_on_the_time_line_not_by_row_order_or_gaps():
    # two weeks apart: days 0, 1 and 14, 15; the held-out day is the last one, day 15
    t = np.concatenate([hourly(2), hourly(2) + 14 * 24.0])
    split = time_split(t, 0.25)
    assert split.days == 4 and split.cut_hours == 15 * 24.0


def test_a_single_day_holds_out_its_last_hours():
    t = np.random.default_rng(1).uniform(6.0, 18.0, 1000)
    split = time_split(t, 0.2)
    assert split.days == 1 and split.cut_hours == np.max(t) - 0.2 * (np.max(t) - np.min(t))
    assert np.all(t[split.held_out] >= split.cut_hours) and 150 < len(split.held_out) < 250


def test_no_hold_out_without_enough_rows_or_with_share_zero():
    assert time_split(hourly(10), 0.0) is None
    assert time_split(np.arange(60.0), 0.2) is None            # too few rows
    assert time_split(np.full(500, 5.0), 0.2) is None          # one instant: nothing to order
