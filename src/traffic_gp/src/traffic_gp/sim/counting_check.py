"""The people counter's output against the simulator's truth (no ROS): what the counting test and
benchmark report.

Inputs are what the real nodes publish: the counter's watches (cells, counts, start, duration),
the laser's scans placed in the map by tf, and the simulator's true people in view at each scan
(robot_sim's `~people_truth`). The reference here is written apart from the counter's code:

- true count of a reported cell in a watch: the different true people whose true position was
  in that cell at a scan of the watch;
- a cell truly seen in a watch: its centre lies within some scan's field of view, no farther than
  the beam nearest to it reached (the simulated laser stops at walls and at people);
- a cell truly hidden in a watch: none of its 3 x 3 sample points lies within a scan's field of
  view no farther than the nearest beam's reading plus a person's diameter (a beam that hits a
  person sees the person's disc, no more).
"""
import math
from dataclasses import dataclass, field
from typing import Dict, List, Sequence, Set, Tuple

import numpy as np

from robot_common.cells import CellGrid

__all__ = ["TrueScan", "CountCheck", "check_counts"]


@dataclass
class TrueScan:
    """A scan as the laser took it (pose from tf, ranges) and the true people in view then."""

    stamp: float
    pose: Tuple[float, float, float]
    angle_min: float
    angle_increment: float
    ranges: np.ndarray
    people: List[Tuple[str, float, float]] = field(default_factory=list)


@dataclass
class CountCheck:
    """Figures of a run: people counted and truly there in the reported cells, seen-cell recall,
    reported cells that were truly hidden."""

    counted: int = 0
    truth: int = 0
    truly_seen: int = 0
    seen_and_reported: int = 0
    reported: int = 0
    hidden_reported: int = 0
    watches: int = 0

    @property
    def count_ratio(self) -> float:
        return self.counted / self.truth if self.truth else math.nan

    @property
    def recall(self) -> float:
        return self.seen_and_reported / self.truly_seen if self.truly_seen else math.nan

    def line(self) -> str:
        return (f"{self.watches} watches: counted {self.counted} people, truly {self.truth} in the "
                f"reported cells (ratio {self.count_ratio:.3f}); seen-cell recall {self.recall:.3f} "
                f"({self.seen_and_reported}/{self.truly_seen}); reported cells truly hidden "
                f"{self.hidden_reported} of {self.reported}")


def _within(scan: TrueScan, px: np.ndarray, py: np.ndarray, extra: float) -> np.ndarray:
    """Points in the scan's field of view no farther than their nearest beam's reading + extra."""
    x, y, yaw = scan.pose
    dx, dy = px - x, py - y
    bearing = np.arctan2(dy, dx) - yaw - scan.angle_min
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi        # -pi..pi from angle_min
    bearing = np.where(bearing < -scan.angle_increment / 2, bearing + 2 * math.pi, bearing)
    beam = np.rint(bearing / scan.angle_increment).astype(int)
    ok = (beam >= 0) & (beam < len(scan.ranges))
    reading = np.where(ok, scan.ranges[np.clip(beam, 0, len(scan.ranges) - 1)], -np.inf)
    reading = np.where(np.isnan(reading), -np.inf, reading)
    return ok & (np.hypot(dx, dy) <= reading + extra)


def _watch_truth(cells: CellGrid, scans: Sequence[TrueScan], index: Sequence[int],
                 person_radius: float):
    """(true people per cell, truly seen cells, truly hidden cells among `index`) of a watch."""
    people: Dict[int, Set[str]] = {}
    seen: Set[int] = set()
    visible_any = np.zeros(len(index), dtype=bool)
    offsets = np.array([-1, 0, 1]) * cells.cell_size / 3
    sx = (cells.x[np.asarray(index, dtype=np.int64)][:, None] + np.repeat(offsets, 3)[None, :])
    sy = (cells.y[np.asarray(index, dtype=np.int64)][:, None] + np.tile(offsets, 3)[None, :])
    for scan in scans:
        for name, px, py in scan.people:
            cell = int(cells.index_at(np.array([px]), np.array([py]))[0])
            people.setdefault(cell, set()).add(name)
        x, y, _ = scan.pose
        near = np.nonzero(np.hypot(cells.x - x, cells.y - y) <= np.nanmax(scan.ranges) + 1.0)[0]
        seen.update(near[_within(scan, cells.x[near], cells.y[near], 0.0)].tolist())
        if len(index):
            visible_any |= _within(scan, sx, sy, 2 * person_radius).any(axis=1)
    hidden = {cell for cell, ok in zip(index, visible_any.tolist()) if not ok}
    return people, seen, hidden


def check_counts(cells: CellGrid, watches, scans: Sequence[TrueScan], *,
                 person_radius: float = 0.25, max_range: float = math.inf) -> CountCheck:
    """Compare the counter's `watches` (objects with start, duration, cells (indices), counts)
    with the truth of the `scans` taken during each (see the module docstring)."""
    result = CountCheck()
    stamps = np.array([scan.stamp for scan in scans])
    for watch in watches:
        inside = (stamps >= watch.start - 1e-6) & (stamps <= watch.start + watch.duration + 1e-6)
        chosen = [scans[i] for i in np.nonzero(inside)[0]]
        if not chosen:
            continue
        index = [int(i) for i in watch.cells]
        people, seen, hidden = _watch_truth(cells, chosen, index, person_radius)
        seen = {cell for cell in seen
                if min(math.hypot(cells.x[cell] - s.pose[0], cells.y[cell] - s.pose[1])
                       for s in chosen) <= max_range - cells.cell_size}
        reported = set(index)
        result.watches += 1
        result.counted += int(np.sum(watch.counts))
        result.truth += sum(len(people.get(cell, ())) for cell in reported)
        result.truly_seen += len(seen)
        result.seen_and_reported += len(seen & reported)
        result.reported += len(reported)
        result.hidden_reported += len(hidden)
    return result
