"""People in the hallways: a simulator with known ground truth, for learning crowd maps.

Cells, time of week, views and exposure are the shared vocabulary (`robot_common.cells`). Each free
cell has a true people density (people per m^2) that varies over the day and the week
(`PeopleSimulator.density`): busy main halls, quiet back halls, a daytime envelope with a lunch
bump, rushes in the ~10 minutes before the hour when classes start, quiet weekends. Robots watch
the halls from random places at random times; each `View` lists only the
cells the robot actually saw (ray cast in the map) with the seen part of each cell and the people
counted there (Poisson), so "seen, nobody there" (count 0) differs from "not seen" (absent).

Counts over a watch of `duration` seconds include people who walked in meanwhile: the expected
count in a cell is `density * seen_area * (1 + duration / dwell_time)` (`exposure`).
Time is hours since Monday 00:00 (`hours_of_week` converts UNIX time). On a generated `Building`
the halls and their `busy` levels come from the building; on other maps (map_server files) they
are derived from the free space (`derive_halls`: skeleton of the free space split at junctions,
corridor widths from the distance transform, the longest/widest corridors "main").
"""
import math
from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

import numpy as np
from scipy import ndimage

from robot_common.cells import DWELL_TIME_S, HOURS_PER_WEEK, CellGrid, View, exposure, visible_cells
from robot_common.maps import GridMap
from robot_sim.building import Building
from robot_sim.errors import SimError


@dataclass
class HallLayout:
    """Per-cell hall labels: `hall` index (-1: not a hall), its `busy` level and main flag."""

    names: List[str]
    busy: np.ndarray       # per cell
    hall: np.ndarray       # per cell
    main: np.ndarray       # per cell, bool
    hotspots: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (x, y) of class doors


@dataclass(frozen=True)
class Schedule:
    """When people move: classes start on the hour from `first_class` to `last_class` on class days."""

    first_class: int = 9
    last_class: int = 17
    class_days: Tuple[int, ...] = (0, 1, 2, 3, 4)
    rush_minutes: float = 10.0       # people fill the halls in the last minutes before the hour
    weekend_level: float = 0.25


class PeopleSimulator:
    """True people densities per cell over the week, and robots' views with Poisson counts.

    Args:
        cells: the cell grid.
        layout: which cells are halls, how busy, which are main halls.
        peak_density: people per m^2 in a main hall on a weekday afternoon, outside rushes.
        rush_gain: extra factor at the peak of a rush in a main hall (scaled by `busy`).
        room_busy: busy level of free cells outside halls.
        schedule: the class timetable.
        seed: seeds the robots' places, times and counts.
    """

    def __init__(self, cells: CellGrid, layout: HallLayout, *, peak_density: float = 0.15,
                 rush_gain: float = 3.0, room_busy: float = 0.08, night_level: float = 0.03,
                 schedule: Schedule = Schedule(), dwell_time: float = DWELL_TIME_S, seed: int = 0):
        self.cells, self.layout, self.schedule = cells, layout, schedule
        self.peak_density, self.rush_gain, self.night_level = peak_density, rush_gain, night_level
        self.dwell_time = dwell_time
        self.busy = np.where(layout.hall >= 0, layout.busy, room_busy)
        self.rush_weight = np.where(layout.hall >= 0, layout.busy, 0.0) * self._spots()
        self.rng = np.random.default_rng(seed)
        self.vis_grid = cells.grid.downsample(max(1, int(0.1 / cells.grid.resolution)))

    @classmethod
    def from_building(cls, building: Building, cell_size: float = 0.5, **options):
        cells = CellGrid.from_map(building.grid, cell_size)
        return cls(cells, building_layout(building, cells), **options)

    @classmethod
    def from_map(cls, grid: GridMap, cell_size: float = 0.5, **options):
        cells = CellGrid.from_map(grid, cell_size)
        return cls(cells, derive_halls(grid, cells), **options)

    def _spots(self) -> np.ndarray:
        spots = np.zeros(self.cells.n_cells)
        for hx, hy in self.layout.hotspots:
            bump = np.exp(-((self.cells.x - hx) ** 2 + (self.cells.y - hy) ** 2) / (2 * 2.0 ** 2))
            spots = np.maximum(spots, bump)
        return 1.0 + spots

    def day_level(self, t) -> np.ndarray:
        """Activity over the day (about 1 on weekday afternoons), lower at night and weekends."""
        t = np.mod(np.asarray(t, dtype=float), HOURS_PER_WEEK)
        hour, day = np.mod(t, 24.0), np.floor(t / 24.0)
        rise = 1.0 / (1.0 + np.exp(-(hour - 8.0) / 0.6))
        fall = 1.0 / (1.0 + np.exp((hour - 18.5) / 0.8))
        lunch = 0.5 * np.exp(-0.5 * ((hour - 12.5) / 0.6) ** 2)
        level = self.night_level + (1.0 - self.night_level) * rise * fall + lunch * rise
        weekday = np.isin(day, self.schedule.class_days)
        return np.where(weekday, level, level * self.schedule.weekend_level)

    def rush_level(self, t) -> np.ndarray:
        """0..1: how close `t` is to the peak of a rush before a class starts on the hour."""
        t = np.mod(np.asarray(t, dtype=float), HOURS_PER_WEEK)
        hour, day = np.mod(t, 24.0), np.floor(t / 24.0)
        start = np.round(hour)                                    # the nearest full hour
        minutes = (hour - start) * 60.0                           # negative before it
        half = self.schedule.rush_minutes * 0.9
        centre = -self.schedule.rush_minutes * 0.7
        bump = np.where(np.abs(minutes - centre) < half,
                        0.5 * (1.0 + np.cos(math.pi * (minutes - centre) / half)), 0.0)
        classes = (start >= self.schedule.first_class) & (start <= self.schedule.last_class)
        return bump * (classes & np.isin(day, self.schedule.class_days))

    def density(self, t, cells=None) -> np.ndarray:
        """True people per m^2: shape (len(t), len(cells)) for arrays, cells default all."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        idx = np.arange(self.cells.n_cells) if cells is None else np.asarray(cells)
        return self.density_at(t[:, None], idx[None, :])

    def density_at(self, t, cells) -> np.ndarray:
        """True people per m^2 at pairs (t[i], cells[i]) (broadcast)."""
        t, idx = np.asarray(t, dtype=float), np.asarray(cells)
        return self.peak_density * self.busy[idx] * self.day_level(t) * (
            1.0 + self.rush_gain * self.rush_level(t) * self.rush_weight[idx])

    def expected_count(self, t, cells=None) -> np.ndarray:
        """True expected people in whole cells at times `t` (one snapshot)."""
        return self.density(t, cells) * self.cells.cell_area

    def observe(self, n_views: int, *, robots: int = 1, start: float = 0.0, hours: float = 168.0,
                radius: float = 4.0, duration: float = 0.0, hall_share: float = 0.8,
                progress: bool = False) -> List[View]:
        """`n_views` views from `robots` robots at random places and times in [start, start+hours)."""
        if n_views < 0 or robots < 1 or hours <= 0 or radius <= 0:
            raise SimError(f"bad observation request: n_views={n_views} robots={robots} "
                           f"hours={hours} radius={radius}")
        times = np.sort(start + self.rng.uniform(0.0, hours, n_views))
        places = self.random_places(n_views, hall_share)
        views = []
        iterator = range(n_views)
        if progress:
            from tqdm import tqdm
            iterator = tqdm(iterator, desc="simulating views", unit="view", mininterval=1.0)
        for i in iterator:
            x, y = places[i]
            cells, fractions = visible_cells(self.cells, x, y, radius, vis_grid=self.vis_grid)
            mean = self.density(times[i], cells)[0] * exposure(
                fractions * self.cells.cell_area, duration, self.dwell_time)
            views.append(View(f"robot_{i % robots}", float(times[i]), float(x), float(y),
                              float(duration), cells, fractions, self.rng.poisson(mean)))
        return views

    def random_places(self, n: int, hall_share: float = 0.8) -> np.ndarray:
        """`n` places (x, y): `hall_share` of them in hall cells, the rest in any cell."""
        halls = np.nonzero(self.layout.hall >= 0)[0]
        pool_all = np.arange(self.cells.n_cells)
        in_hall = self.rng.random(n) < hall_share if halls.size else np.zeros(n, bool)
        chosen = np.where(in_hall, self.rng.choice(halls if halls.size else pool_all, n),
                          self.rng.choice(pool_all, n))
        jitter = (self.rng.random((n, 2)) - 0.5) * self.cells.cell_size * 0.9
        return np.column_stack([self.cells.x[chosen], self.cells.y[chosen]]) + jitter

    def people_on_route(self, route_cells: Sequence[int], times) -> int:
        """People met along a route: Poisson counts in each route cell at the time it is passed."""
        mean = np.array([self.expected_count(t, [c])[0, 0] for c, t in zip(route_cells, times)])
        return int(self.rng.poisson(mean).sum())


def building_layout(building: Building, cells: CellGrid) -> HallLayout:
    """Halls of a generated building; class doors (on the main hall) are rush hot spots."""
    halls = building.halls
    hall = np.full(cells.n_cells, -1)
    busy = np.zeros(cells.n_cells)
    for number, area in enumerate(halls):
        x0, y0, x1, y1 = area.box
        inside = (cells.x >= x0) & (cells.x <= x1) & (cells.y >= y0) & (cells.y <= y1)
        hall[inside], busy[inside] = number, area.busy
    top = max(halls, key=lambda area: area.busy)
    main = hall == halls.index(top)
    spots = []
    for room in building.rooms:
        if room.label.startswith("classroom"):
            door_y = top.box[1] if room.centre[1] < top.box[1] else top.box[3]
            spots.append((room.centre[0], door_y))
    return HallLayout([area.name for area in halls], busy, hall, main,
                      np.array(spots, dtype=float).reshape(-1, 2))


def derive_halls(grid: GridMap, cells: CellGrid, *, max_width: float = 4.0,
                 min_length: float = 6.0, main_share: float = 0.5, back_busy: float = 0.3,
                 work_resolution: float = 0.2, junction: float = 0.8) -> HallLayout:
    """Corridors of a map from its free space. A free spot is in a corridor when, along one of 8
    directions, the free run through it is at least `min_length` long while the run across it
    is at most `max_width` (rooms and open areas are not elongated). Corridor spots of about the
    same direction that touch form a hall; the largest halls, up to `main_share` of the corridor
    area, are main halls (busy 1), the others back halls (`back_busy`). Junctions and corridor
    ends within `junction` metres (through long free runs, so not into rooms) join the nearest
    hall."""
    work = grid.downsample(max(1, int(round(work_resolution / grid.resolution))))
    free = ndimage.binary_opening(work.free_mask(), iterations=1)
    runs = _free_runs(free, work.resolution, 8, max(min_length, max_width) + work.resolution)
    ok = (runs >= min_length) & (np.roll(runs, 4, axis=0) <= max_width) & free
    direction = np.argmax(np.where(ok, runs, -1.0), axis=0)
    orientation = ((direction + 1) // 2) % 4              # 4 classes of neighbouring directions
    corridor = ok.any(axis=0)
    pieces, masks = [], []
    reach = int(round(junction / 2 / work.resolution))
    disk = np.hypot(*np.mgrid[-reach:reach + 1, -reach:reach + 1]) <= reach
    for klass in range(4):     # closing bridges the gaps that doorways cut into a hall
        closed = ndimage.binary_closing(corridor & (orientation == klass), disk) & free
        labels, count = ndimage.label(closed, np.ones((3, 3)))
        areas = np.bincount(labels.ravel(), minlength=count + 1) * work.resolution ** 2
        for number in range(1, count + 1):
            if areas[number] >= min_length * work.resolution * 4:
                pieces.append((areas[number], len(masks)))
                masks.append(labels == number)
    pieces.sort(reverse=True)
    hall_px = np.full(free.shape, -1)
    main_ids, covered = set(), 0.0
    total = sum(area for area, _ in pieces)
    for rank, (area, _) in enumerate(pieces):
        if covered < main_share * total:
            main_ids.add(rank)
            covered += area
    for rank, (_, number) in reversed(list(enumerate(pieces))):   # larger halls win overlaps
        hall_px[masks[number]] = rank
    long_ = free & (runs.max(axis=0) >= min_length)     # not into rooms: they are short
    for _ in range(int(round(junction / work.resolution))):   # grow through free space only
        grown = ndimage.grey_dilation(hall_px, size=(3, 3))
        hall_px = np.where((hall_px < 0) & long_ & (grown >= 0), grown, hall_px)
    row, col = work.world_to_cell(cells.x, cells.y)
    row, col = np.clip(row, 0, work.height - 1), np.clip(col, 0, work.width - 1)
    hall = hall_px[row, col]
    main = np.isin(hall, list(main_ids))
    busy = np.where(main, 1.0, np.where(hall >= 0, back_busy, 0.0))
    names = [f"{'main' if r in main_ids else 'back'}_hall_{r}" for r in range(len(pieces))]
    return HallLayout(names, busy, hall, main, _main_hotspots(cells, main))


def _main_hotspots(cells: CellGrid, main: np.ndarray, spacing: float = 8.0) -> np.ndarray:
    """Rush hot spots every `spacing` metres along the main halls (stand-ins for class doors)."""
    if not main.any():
        return np.zeros((0, 2))
    points = np.column_stack([cells.x[main], cells.y[main]])
    keep = [points[0]]
    for point in points[1:]:
        if min(np.hypot(*(point - other)) for other in keep) >= spacing:
            keep.append(point)
    return np.array(keep)


def _free_runs(free: np.ndarray, resolution: float, directions: int, cap: float) -> np.ndarray:
    """Length (m, capped at `cap`) of the free run through each pixel along `directions`
    directions spread over 180 degrees: shape (directions, H, W)."""
    height, width = free.shape
    rows, cols = np.mgrid[0:height, 0:width]
    steps = int(np.ceil(cap / resolution))
    runs = np.zeros((directions,) + free.shape)
    padded = np.pad(free, 1)
    for k in range(directions):
        angle = math.pi * k / directions
        for sign in (1.0, -1.0):
            alive = free.copy()
            for step in range(1, steps + 1):
                r = np.round(rows + sign * step * math.sin(angle)).astype(int)
                c = np.round(cols + sign * step * math.cos(angle)).astype(int)
                alive &= padded[np.clip(r, -1, height) + 1, np.clip(c, -1, width) + 1]
                runs[k] += alive
    return np.minimum((runs + free) * resolution, cap)
