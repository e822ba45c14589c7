"""Time-ordered hold-out: the most recent whole days of the rows, never random rows.

A crowd map is used to forecast the next days, so every choice `TrafficGP.fit` makes (early
stopping, the anneal, the settings, the served forecaster, the interval width) is judged on
the last days of the training period, forecast from the days before them. Random rows of the
same days would measure interpolation and favour whatever follows each day most closely.

Times are hours since a Monday 00:00 (`Observations.t`, counting on across weeks: hour 170 is
Monday 02:00 of the second week); a day is `floor(t / 24)`. With `share` of the days held out:
  - 28 or more days: the last 7 (a whole week: every weekday once);
  - 2 to 27 days: the last round(share x days) days, at least 1;
  - a single day: the last `share` of its time span;
and no hold-out at all when the held-out part would have fewer than MIN_ROWS rows, or when
`share` is 0. NumPy only.
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np

MIN_ROWS = 50           # fewer held-out rows than this: no hold-out
WEEK_DAYS = 28          # from this many days on, the last whole week is held out


@dataclass
class TimeSplit:
    """Row indices of the fitting part and of the held-out (most recent) part."""

    fit: np.ndarray
    held_out: np.ndarray
    cut_hours: float          # held-out rows have t >= cut_hours
    days: int                 # whole days in the data
    held_out_days: float      # days held out (a share of one day for single-day data)

    def describe(self) -> str:
        days = (f"{self.held_out_days:g} of {self.days} days" if self.days > 1
                else f"the last {self.held_out_days:.0%} of the day")
        return (f"time-ordered hold-out: {days} (t >= {self.cut_hours:g} h; "
                f"{len(self.fit)} fitting rows, {len(self.held_out)} held out)")

    def to_dict(self) -> dict:
        return {"cut_hours": float(self.cut_hours), "days": int(self.days),
                "held_out_days": float(self.held_out_days), "fit_rows": int(len(self.fit)),
                "held_out_rows": int(len(self.held_out))}


def time_split(t, share: float = 0.2, min_rows: int = MIN_ROWS) -> Optional[TimeSplit]:
    """The time-ordered hold-out of rows at times `t` (hours), or None (see the module)."""
    t = np.asarray(t, float).ravel()
    if share <= 0 or t.size < 2 * min_rows:
        return None
    day = np.floor(t / 24.0)
    days = np.unique(day)
    if days.size >= WEEK_DAYS:
        held_days = 7.0
        cut = float(days[-7] * 24.0)
    elif days.size >= 2:
        held_days = float(min(max(int(round(share * days.size)), 1), days.size - 1))
        cut = float(days[-int(held_days)] * 24.0)
    else:
        low, high = float(t.min()), float(t.max())
        if high <= low:
            return None
        held_days = share
        cut = high - share * (high - low)
    held_out = np.nonzero(t >= cut)[0]
    fit = np.nonzero(t < cut)[0]
    if held_out.size < min_rows or fit.size < min_rows:
        return None
    return TimeSplit(fit, held_out, cut, int(days.size), held_days)
