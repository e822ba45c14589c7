"""People counts from a robot's own laser and people tracker (no ROS): what `people_counter`
publishes as robot_common/PeopleCount.

Each scan is placed in the map at the laser's pose. A point of the map is seen by a scan when it
lies within the scanner's field of view and range and no closer than where its beam stops: the
measured range (a person or an unmapped obstacle), the map's walls (ray cast in the map, so a
scan never sees through a mapped wall) and the tracked people's discs (a beam that reaches a
person sees the person's disc, not what is behind it).
A cell's seen part in a scan is the share of its `sub` x `sub` sample points that are seen.

A watch (`watch` seconds of scans) becomes one count message whose semantics are those of
`robot_common.cells.exposure`: the expected count of a cell watched for `duration` seconds with
seen part f is density x f x area x (1 + duration / dwell_time), counting everyone who was in its
seen part at any time of the watch once. Each tracked person (a track `name`) is therefore
counted once per cell and watch, however many scans saw it there; a track counts only once it
has been detected in `min_detections` scans (short-lived false tracks do not count); untracked
detections (empty names) count as the most of them seen in the cell by any one scan. A cell seen
only part of the watch, or by a moving robot, has the exposure of its first look (its largest
seen part) plus the people who may have walked in while it was seen (seen part x seen seconds /
dwell_time); its reported `fraction` is that exposure divided by area x (1 + duration /
dwell_time), so the crowd model reads exactly that exposure back.

A tracked person is seen by a scan when some beam reaches their disc (not only the beam nearest
their reported centre: in a crowd a person is often half hidden, and the tracked position is
noisy). A track's detections are the people messages it was reported in (`seen_at`): a message
used for two scans confirms its tracks once. A finished watch is held `confirm_time` seconds of
scans more before it is returned, so that a person first seen at its end whose track is confirmed
just after it still counts in it.
"""
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Set, Tuple

import numpy as np

from robot_common.cells import DWELL_TIME_S, CellGrid
from robot_common.maps import beam_indices, beam_reach, ray_disc_hits, raycast
from traffic_gp.errors import TrafficError

__all__ = ["Detection", "Scan", "Watch", "PeopleCounter", "beam_ranges", "seen_points",
           "people_seen"]


@dataclass(frozen=True)
class Detection:
    """A person at (x, y) in the map frame; `name` is the track id ("" for an untracked one)."""

    name: str
    x: float
    y: float


@dataclass
class Scan:
    """One laser scan placed in the map: the laser's pose, its beams (angles relative to the
    laser, radians, evenly spaced) and their ranges as the scanner reported them."""

    stamp: float                       # seconds
    pose: Tuple[float, float, float]   # laser x, y, yaw in the map frame
    angles: np.ndarray
    ranges: np.ndarray
    range_min: float = 0.0
    range_max: float = math.inf


@dataclass
class Watch:
    """The counts of one watch: cells seen (indices), the exposure-equivalent seen part of each,
    the people counted in each, when it started, how long it lasted, where the robot was."""

    start: float
    duration: float
    x: float
    y: float
    cells: np.ndarray
    fractions: np.ndarray
    counts: np.ndarray


@dataclass
class _Open:
    """A watch being accumulated."""

    start: float
    last: float
    poses: List[Tuple[float, float]] = field(default_factory=list)
    first_look: Dict[int, float] = field(default_factory=dict)    # cell -> largest seen part
    seen_time: Dict[int, float] = field(default_factory=dict)     # cell -> sum of part x seconds
    tracks: Dict[int, Set[str]] = field(default_factory=dict)     # cell -> track names seen there
    untracked: Dict[int, int] = field(default_factory=dict)       # cell -> most in one scan


def beam_ranges(scan: Scan, vis_grid, people: Sequence[Detection], *, max_range: float,
                person_radius: float) -> np.ndarray:
    """How far each beam sees (m), never beyond the map's walls (ray cast in the map). A beam
    whose reading is at a tracked person's disc (not shorter than the disc, not more than a
    radius beyond its far side) sees up to the disc's far side, at most a diameter beyond the
    reading (tracked positions are noisy): the person's spot is seen, what is behind is not. Any
    other beam sees its reading plus a person's radius (a person the tracker missed: their
    centre); so does a beam that reads farther than a tracked disc it crosses: it passed that
    spot (the tracked position is off by a few centimetres at the disc's edge, or a false
    track). Readings are read by robot_common.maps.beam_reach (REP 117): an invalid one sees
    nothing, no return sees to range_max."""
    x, y, yaw = scan.pose
    measured = beam_reach(scan.ranges, scan.range_min, scan.range_max)
    reach = min(max_range, scan.range_max)
    world = yaw + np.asarray(scan.angles, dtype=float)
    near, far = ray_disc_hits(x, y, world, [(person.x, person.y) for person in people],
                              person_radius)
    on_person = (np.isfinite(near) & (measured >= near - person_radius)
                 & (measured <= far + person_radius))
    stops = np.where(on_person, np.minimum(far, measured + 2 * person_radius),
                     measured + person_radius)
    walls = raycast(vis_grid, x, y, world, reach)
    return np.maximum(np.minimum(np.minimum(stops, walls), reach), 0.0)


def seen_points(scan: Scan, stops: np.ndarray, px, py, *, tolerance: float = 1e-6) -> np.ndarray:
    """Which world points the scan saw: in the field of view and no farther than their beam."""
    x, y, _ = scan.pose
    beam = beam_indices(scan.pose, scan.angles, px, py)
    inside = beam >= 0
    dist = np.hypot(np.asarray(px, dtype=float) - x, np.asarray(py, dtype=float) - y)
    result = np.zeros(np.shape(dist), dtype=bool)
    result[inside] = dist[inside] <= stops[beam[inside]] + tolerance
    return result


def people_seen(scan: Scan, stops: np.ndarray, px, py, radius: float) -> np.ndarray:
    """Which people (centres px, py) the scan saw: some beam through their disc of `radius` stops
    no nearer than where it enters the disc (a person behind another, or behind a wall, is not
    seen; one half hidden is). A zero radius tests the centre's beam."""
    px, py = np.asarray(px, dtype=float), np.asarray(py, dtype=float)
    if radius <= 0:
        return seen_points(scan, stops, px, py)
    x, y, yaw = scan.pose
    world = yaw + np.asarray(scan.angles, dtype=float)
    seen = np.zeros(px.shape, dtype=bool)
    for k, centre in enumerate(zip(px.tolist(), py.tolist())):
        entry, _ = ray_disc_hits(x, y, world, [centre], radius)     # inf: the beam misses it
        seen[k] = bool(np.any(stops >= entry - 1e-6))
    return seen


class PeopleCounter:
    """Turns scans and tracked people into watches of per-cell counts (see the module docstring).

    Args:
        cells: the map's cells (the crowd model's cells: same map and cell size).
        watch: seconds of scans per count message.
        max_range: metres of a scan used for counting (the scanner's range_max caps it too).
        person_radius: metres; a tracked person's disc occludes what is behind it.
        dwell_time: seconds a person stays in view of one cell (the crowd model's `dwell_time`).
        min_detections: detections (people messages) a track needs before it counts.
        max_gap: the most seconds one scan stands for (a pause in the scans is not watching).
        sub: sample points per cell side.
        vis_resolution: metres; the map is ray cast at about this resolution.
        smoothing: weight of a new detection in a track's smoothed position (1: none).
        cell_margin: metres a track's smoothed position must be beyond its cell to move on.
        confirm_time: seconds of scans a finished watch waits for its tracks' confirmation.
    """

    def __init__(self, cells: CellGrid, *, watch: float = 10.0, max_range: float = 8.0,
                 person_radius: float = 0.25, dwell_time: float = DWELL_TIME_S,
                 min_detections: int = 3, max_gap: float = 0.5, sub: int = 3,
                 vis_resolution: float = 0.1, smoothing: float = 0.3, cell_margin: float = 0.1,
                 confirm_time: float = 1.0):
        if not (watch > 0 and max_range > 0 and person_radius >= 0 and dwell_time > 0
                and max_gap > 0 and sub >= 1 and min_detections >= 1 and 0 < smoothing <= 1
                and cell_margin >= 0 and 0 <= confirm_time < watch):
            raise TrafficError(f"bad counter settings: watch={watch} max_range={max_range} "
                               f"person_radius={person_radius} dwell_time={dwell_time} "
                               f"max_gap={max_gap} sub={sub} min_detections={min_detections} "
                               f"confirm_time={confirm_time} (0 <= confirm_time < watch)")
        self.cells, self.watch, self.max_range = cells, watch, max_range
        self.person_radius, self.dwell_time = person_radius, dwell_time
        self.min_detections, self.max_gap = min_detections, max_gap
        self.smoothing, self.cell_margin = smoothing, cell_margin
        self.confirm_time = confirm_time
        self.vis_grid = cells.grid.downsample(
            max(1, int(round(vis_resolution / cells.grid.resolution))))
        offsets = (np.arange(sub) + 0.5) / sub - 0.5
        self._dx = np.repeat(offsets, sub) * cells.cell_size
        self._dy = np.tile(offsets, sub) * cells.cell_size
        self._hits: Dict[str, int] = {}       # track -> people messages it was in
        self._tracks: Dict[str, List] = {}    # track -> [smoothed x, y, its cell]
        self._last_seen: Dict[str, float] = {}
        self._open: Optional[_Open] = None
        self._ended: List[_Open] = []        # ended, waiting confirm_time for confirmations

    def add(self, scan: Scan, people: Sequence[Detection], *,
            seen_at: Optional[float] = None) -> Optional[Watch]:
        """Take one scan and the people detected at its time (`seen_at`: the stamp of their people
        message, default the scan's); a finished watch, if one is done: a watch ends at the scan
        that starts the next and is returned `confirm_time` seconds of scans later."""
        finished = self._due(scan.stamp)
        if self._open is None:
            self._open = _Open(scan.stamp, scan.stamp)
        current = self._open
        seconds = min(max(scan.stamp - current.last, 0.0), self.max_gap)
        current.last = scan.stamp
        current.poses.append(scan.pose[:2])
        stops = beam_ranges(scan, self.vis_grid, people, max_range=self.max_range,
                            person_radius=self.person_radius)
        index, parts = self._cells_seen(scan, stops)
        for cell, part in zip(index.tolist(), parts.tolist()):
            current.first_look[cell] = max(current.first_look.get(cell, 0.0), part)
            current.seen_time[cell] = current.seen_time.get(cell, 0.0) + part * seconds
        self._count(scan, stops, people, set(index.tolist()),
                    scan.stamp if seen_at is None else seen_at)
        return finished

    def _due(self, stamp: float) -> Optional[Watch]:
        """End the open watch if a scan at `stamp` ends it; the oldest ended watch whose
        confirm_time has passed (at once when time went back), if any."""
        current = self._open
        if current is not None and (stamp < current.last or stamp - current.start >= self.watch):
            self._ended.append(current)
            self._open = None
        for ended in self._ended:
            if stamp < ended.last or stamp - ended.last >= self.confirm_time:
                self._ended.remove(ended)
                return self._finish(ended)
        return None

    def _cells_seen(self, scan: Scan, stops: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        x, y, _ = scan.pose
        reach = float(stops.max(initial=0.0)) + self.cells.cell_size
        near = np.nonzero((np.abs(self.cells.x - x) <= reach) & (np.abs(self.cells.y - y) <= reach))[0]
        px = self.cells.x[near, None] + self._dx[None, :]
        py = self.cells.y[near, None] + self._dy[None, :]
        parts = seen_points(scan, stops, px, py).mean(axis=1)
        keep = parts > 0
        return near[keep], parts[keep]

    def _count(self, scan: Scan, stops: np.ndarray, people: Sequence[Detection],
               seen: Set[int], seen_at: float) -> None:
        if not people:
            return
        current = self._open
        px = np.array([p.x for p in people])
        py = np.array([p.y for p in people])
        visible = people_seen(scan, stops, px, py, self.person_radius)
        where = self.cells.index_at(px, py)
        untracked: Dict[int, int] = {}
        for person, ok, cell in zip(people, visible.tolist(), where.tolist()):
            if not ok or cell < 0:
                continue
            if person.name:
                cell = self._track_cell(person, cell, seen_at)
                if cell in seen:
                    current.tracks.setdefault(cell, set()).add(person.name)
            elif cell in seen:
                untracked[cell] = untracked.get(cell, 0) + 1
        for cell, number in untracked.items():
            current.untracked[cell] = max(current.untracked.get(cell, 0), number)

    def _track_cell(self, person: Detection, cell: int, seen_at: float) -> int:
        """The cell a track is in: its position smoothed over its detections, and a new cell
        only once the smoothed position is `cell_margin` beyond the old one (a person standing
        at a cell's edge is not counted in both cells as the position jitters). A detection
        counts once per people message (`seen_at`)."""
        if self._last_seen.get(person.name) != seen_at:
            self._hits[person.name] = self._hits.get(person.name, 0) + 1
        self._last_seen[person.name] = seen_at
        state = self._tracks.get(person.name)
        if state is None:
            self._tracks[person.name] = [person.x, person.y, cell]
            return cell
        weight = self.smoothing
        state[0] += weight * (person.x - state[0])
        state[1] += weight * (person.y - state[1])
        old = state[2]
        beyond = max(abs(state[0] - self.cells.x[old]), abs(state[1] - self.cells.y[old]))
        if beyond > self.cells.cell_size / 2 + self.cell_margin:
            now = int(self.cells.index_at(np.array([state[0]]), np.array([state[1]]))[0])
            state[2] = now if now >= 0 else old
        return state[2]

    def flush(self) -> Optional[Watch]:
        """End the watches now: the one waiting for confirmations if any, else the open one
        (call again for the next; None when no scan came since the last watch)."""
        if self._ended:
            return self._finish(self._ended.pop(0))
        current, self._open = self._open, None
        return None if current is None else self._finish(current)

    def _finish(self, current: _Open) -> Watch:
        """The counts of an ended watch, its tracks confirmed as they are now."""
        duration = current.last - current.start
        index = np.array(sorted(current.first_look), dtype=np.int64)
        exposure = np.array([current.first_look[c] + current.seen_time[c] / self.dwell_time
                             for c in index.tolist()])
        fractions = np.clip(exposure / (1.0 + duration / self.dwell_time), 1e-6, 1.0)
        counts = np.array([self._people_in(current, c) for c in index.tolist()], dtype=np.int64)
        x, y = np.mean(np.asarray(current.poses), axis=0)
        self._forget(current.last)
        return Watch(current.start, duration, float(x), float(y), index, fractions, counts)

    def _people_in(self, current: _Open, cell: int) -> int:
        names = current.tracks.get(cell, ())
        confirmed = sum(1 for name in names if self._hits.get(name, 0) >= self.min_detections)
        return confirmed + current.untracked.get(cell, 0)

    def _forget(self, now: float, after: float = 60.0) -> None:
        """Drop tracks not seen for `after` seconds (bounded memory on a long-running robot)."""
        for name in [n for n, last in self._last_seen.items() if now - last > after]:
            del self._last_seen[name], self._hits[name], self._tracks[name]
