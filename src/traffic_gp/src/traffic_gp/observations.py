"""People counts as rows for the models: where (x, y in metres, map frame), when (`t`, hours since
a Monday 00:00, counting on across weeks: 170 is Monday 02:00 of the second week; the models use
`t` modulo their period, and `fit` holds out the most recent days by it), how much was watched
(`exposure`, effective m^2) and how many people were counted. `hours_since_monday` turns UNIX
times into such hours (the node's rows).

A robot's view becomes one row per seen cell (`from_views`), so cells seen empty give rows with
count 0 while unseen cells give no row at all. A sensor that reports only one total count for
its whole view gives one row at the centre of the seen area (`aggregate_view`): exact when the
density is even over the view, an approximation otherwise.
"""
import datetime
from dataclasses import dataclass
from typing import Iterable, Optional, Sequence

import numpy as np

from robot_common.cells import DWELL_TIME_S, HOURS_PER_WEEK, CellGrid, View, exposure
from traffic_gp.errors import ObservationError

FIELDS = ("x", "y", "t", "exposure", "count")


def hours_since_monday(unix_seconds, utc_offset_hours: Optional[float] = None):
    """Hours of UNIX times since Monday 1969-12-29 00:00 in the given or the local zone (their
    remainder modulo 168 is `robot_common.cells.hours_of_week`)."""
    seconds = np.asarray(unix_seconds, dtype=float)
    if utc_offset_hours is None:
        first = float(seconds.ravel()[0]) if seconds.size else 0.0
        offset = datetime.datetime.fromtimestamp(first).astimezone().utcoffset()
        utc_offset_hours = offset.total_seconds() / 3600.0 if offset else 0.0
    return seconds / 3600.0 + utc_offset_hours + 72.0     # 1970-01-01 was a Thursday


@dataclass
class Observations:
    """Rows of (x, y, t, exposure, count); `robot` optionally names the robot of each row."""

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    exposure: np.ndarray
    count: np.ndarray
    robot: Optional[np.ndarray] = None

    def __post_init__(self):
        for name in FIELDS:
            value = np.asarray(getattr(self, name), dtype=float).ravel()
            if not np.all(np.isfinite(value)):
                raise ObservationError(f"{name} has non-finite values: {value[~np.isfinite(value)][:5]}")
            setattr(self, name, value)
        lengths = {name: getattr(self, name).size for name in FIELDS}
        if len(set(lengths.values())) > 1:
            raise ObservationError(f"observation fields differ in length: {lengths}")
        if np.any(self.exposure <= 0):
            raise ObservationError(f"exposure must be positive, got {self.exposure[self.exposure <= 0][:5]}")
        bad = (self.count < 0) | (self.count != np.round(self.count))
        if np.any(bad):
            raise ObservationError(f"counts must be non-negative integers, got {self.count[bad][:5]}")
        if self.robot is not None:
            self.robot = np.asarray(self.robot).ravel()
            if self.robot.size != self.x.size:
                raise ObservationError(f"robot has {self.robot.size} entries for {self.x.size} rows")

    def __len__(self) -> int:
        return int(self.x.size)

    @classmethod
    def empty(cls) -> "Observations":
        return cls(*[np.zeros(0)] * 5)

    def inputs(self, period: float = HOURS_PER_WEEK) -> np.ndarray:
        """Model inputs: columns x, y and the time of day (or week) modulo `period` hours."""
        return np.column_stack([self.x, self.y, np.mod(self.t, period)])

    def subset(self, index) -> "Observations":
        robot = None if self.robot is None else self.robot[index]
        return Observations(*(getattr(self, name)[index] for name in FIELDS), robot=robot)

    @classmethod
    def concat(cls, parts: Sequence["Observations"]) -> "Observations":
        parts = [part for part in parts if len(part)]
        if not parts:
            return cls.empty()
        robot = None
        if all(part.robot is not None for part in parts):
            robot = np.concatenate([part.robot for part in parts])
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in FIELDS),
                   robot=robot)

    @classmethod
    def from_views(cls, cells: CellGrid, views: Iterable[View],
                   dwell_time: float = DWELL_TIME_S) -> "Observations":
        """One row per seen cell of each view (at the cell centre)."""
        views = list(views)
        if not views:
            return cls.empty()
        index = np.concatenate([np.asarray(v.cells, dtype=np.int64) for v in views])
        if index.size and (index.min() < 0 or index.max() >= cells.n_cells):
            raise ObservationError(f"cell indices outside 0..{cells.n_cells - 1}")
        sizes = [len(v.cells) for v in views]
        fractions = np.concatenate([v.fractions for v in views])
        durations = np.repeat([v.duration for v in views], sizes)
        return cls(cells.x[index], cells.y[index], np.repeat([v.t for v in views], sizes),
                   exposure(fractions * cells.cell_area, durations, dwell_time),
                   np.concatenate([v.counts for v in views]),
                   robot=np.repeat([v.robot_id for v in views], sizes))

    def compress(self, time_bin_hours: float,
                 period: Optional[float] = HOURS_PER_WEEK) -> "Observations":
        """Sum counts and exposures of rows at the same place in the same time bin (of the
        `period`, or of the whole time line with `period=None`, which keeps the time order).

        Exact for a Poisson model whose rate is constant within a bin (sums of Poisson counts);
        keeps memory bounded on a robot that watches for months. Robot names are dropped.
        """
        if not time_bin_hours > 0:
            raise ObservationError(f"time_bin_hours must be positive, got {time_bin_hours}")
        if not len(self):
            return self
        bins = np.floor((self.t if period is None else np.mod(self.t, period)) / time_bin_hours)
        keys = np.column_stack([np.round(self.x, 3), np.round(self.y, 3), bins])
        unique, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        return Observations(unique[:, 0], unique[:, 1], (unique[:, 2] + 0.5) * time_bin_hours,
                            np.bincount(inverse, self.exposure), np.bincount(inverse, self.count))


def aggregate_view(cells: CellGrid, index, fractions, total: int, t: float, *, duration: float = 0.0,
                   dwell_time: float = DWELL_TIME_S, robot: str = "") -> Observations:
    """One row for a view that has a single people count for all its seen cells."""
    index, fractions = np.asarray(index, dtype=np.int64), np.asarray(fractions, dtype=float)
    if index.size == 0:
        raise ObservationError("a view with a total count must have seen at least one cell")
    area = fractions * cells.cell_area
    x = float(np.sum(cells.x[index] * area) / area.sum())
    y = float(np.sum(cells.y[index] * area) / area.sum())
    return Observations([x], [y], [t], [float(exposure(area.sum(), duration, dwell_time))], [total],
                        robot=[robot])
