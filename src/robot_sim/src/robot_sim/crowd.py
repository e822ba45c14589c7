"""Individual people in the halls, a laser that sees them and a people tracker with misses and
false tracks, with known truth (no ROS).

`Crowd` turns the people model's densities (`people.PeopleSimulator.density`) into people: in
each cell people arrive at rate density x area / dwell_time and each stays an exponential time
of mean dwell_time, so at any instant a cell holds Poisson(density x area) people and a cell
watched for d seconds is visited by Poisson(density x area x (1 + d / dwell_time)) different
people: exactly the counts `PeopleSimulator.observe` draws (`robot_common.cells.exposure`). Each
person stands at a random spot of the cell while present and has a name ("p<number>").

`Tracker` is a people tracker's output: each visible person (in the laser's field of view and
range, the centre's beam not stopped before the person) is reported under its own name, with
position noise, and missed in a scan with probability `miss_rate`; false tracks (fresh names,
at random seen spots, each lasting `false_track_scans` scans) make about `false_positive_rate`
of the reported tracks.
"""
import math
from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from robot_common.maps import beam_indices, ray_disc_hits, raycast
from robot_sim.errors import SimError
from robot_sim.people import PeopleSimulator

__all__ = ["Crowd", "Tracker", "Person", "disc_ranges"]


@dataclass(frozen=True)
class Person:
    """A person (true or tracked): name and position in the map frame."""

    name: str
    x: float
    y: float


class Crowd:
    """People arriving in and leaving each cell (see the module docstring)."""

    def __init__(self, sim: PeopleSimulator, *, radius: float = 0.25, seed: int = 0):
        self.sim, self.radius = sim, radius
        self.rng = np.random.default_rng(seed)
        self.cell = np.zeros(0, dtype=np.int64)
        self.xy = np.zeros((0, 2))
        self.names = np.zeros(0, dtype=np.int64)
        self._next = 0
        self.now: Optional[float] = None

    def advance(self, now: float, hours: float) -> None:
        """Move the crowd to `now` (seconds) at the people model's time `hours` (of the week)."""
        density = self.sim.density(hours)[0]
        mean = density * self.sim.cells.cell_area
        if self.now is None:                    # start in the stationary state
            self._arrive(self.rng.poisson(mean))
        elif now > self.now:
            elapsed = now - self.now
            stay = self.rng.random(self.names.size) < math.exp(-elapsed / self.sim.dwell_time)
            self.cell, self.xy, self.names = self.cell[stay], self.xy[stay], self.names[stay]
            # those who arrived meanwhile and are still there (exact for any step: a long gap
            # gives the stationary crowd again, not the arrivals of the whole gap)
            self._arrive(self.rng.poisson(mean * -math.expm1(-elapsed / self.sim.dwell_time)))
        self.now = now if self.now is None else max(now, self.now)

    def _arrive(self, per_cell: np.ndarray) -> None:
        cell = np.repeat(np.arange(per_cell.size), per_cell)
        spot = (self.rng.random((cell.size, 2)) - 0.5) * self.sim.cells.cell_size
        xy = np.column_stack([self.sim.cells.x[cell], self.sim.cells.y[cell]]) + spot
        self.cell = np.concatenate([self.cell, cell])
        self.xy = np.vstack([self.xy, xy])
        self.names = np.concatenate([self.names, self._next + np.arange(cell.size)])
        self._next += cell.size

    def people(self) -> List[Person]:
        return [Person(f"p{n}", float(x), float(y)) for n, (x, y) in zip(self.names, self.xy)]


def disc_ranges(x: float, y: float, angles: np.ndarray, centres: np.ndarray,
                radius: float) -> np.ndarray:
    """Distance along each ray from (x, y) to the first disc of `radius` at `centres` (inf: none)."""
    entry, _ = ray_disc_hits(x, y, angles, centres, radius)
    return np.maximum(entry, 0.0)


class Tracker:
    """A people tracker's reports of a `Crowd` seen by a laser (see the module docstring)."""

    def __init__(self, *, miss_rate: float = 0.1, false_positive_rate: float = 0.1,
                 false_track_scans: int = 2, noise: float = 0.05, seed: int = 0):
        if not (0 <= miss_rate < 1 and 0 <= false_positive_rate < 1 and false_track_scans >= 1
                and noise >= 0):
            raise SimError(f"bad tracker settings: miss_rate={miss_rate} false_positive_rate="
                           f"{false_positive_rate} false_track_scans={false_track_scans} "
                           f"noise={noise}")
        self.miss_rate, self.false_positive_rate = miss_rate, false_positive_rate
        self.false_track_scans, self.noise = false_track_scans, noise
        self.rng = np.random.default_rng(seed)
        self._false: List[Tuple[Person, int]] = []      # false tracks and their scans left
        self._next = 0

    def scan(self, grid, crowd: Crowd, pose: Tuple[float, float, float], angles: np.ndarray,
             max_range: float) -> Tuple[np.ndarray, List[Person], List[Person]]:
        """One scan from the laser `pose`: (ranges with the people in them, the tracker's report,
        the true people visible)."""
        x, y, yaw = pose
        world = yaw + np.asarray(angles, dtype=float)
        ranges = np.minimum(raycast(grid, x, y, world, max_range),
                            disc_ranges(x, y, world, crowd.xy, crowd.radius))
        visible = self._visible(crowd, pose, angles, ranges, max_range)
        truth = [Person(f"p{crowd.names[i]}", *map(float, crowd.xy[i])) for i in visible]
        kept = [p for p in truth if self.rng.random() >= self.miss_rate]
        report = [Person(p.name, *(np.array([p.x, p.y]) + self.rng.normal(0, self.noise, 2)))
                  for p in kept] + self._false_tracks(pose, world, ranges, len(kept))
        return ranges, report, truth

    def _visible(self, crowd: Crowd, pose, angles, ranges, max_range) -> np.ndarray:
        x, y, _ = pose
        if crowd.names.size == 0:
            return np.zeros(0, dtype=np.int64)
        dist = np.hypot(crowd.xy[:, 0] - x, crowd.xy[:, 1] - y)
        beam = beam_indices(pose, angles, crowd.xy[:, 0], crowd.xy[:, 1])
        ok = (beam >= 0) & (dist <= max_range)
        ok[ok] &= ranges[beam[ok]] >= dist[ok] - crowd.radius - 1e-6
        return np.nonzero(ok)[0]

    def _false_tracks(self, pose, world, ranges, n_true: int) -> List[Person]:
        """Carry on the live false tracks; start new ones so that they are about
        `false_positive_rate` of the reported tracks."""
        self._false = [(person, left - 1) for person, left in self._false if left > 1]
        share = self.false_positive_rate
        wanted = share / (1 - share) * max(n_true, 1) / self.false_track_scans
        for _ in range(self.rng.poisson(wanted)):
            beam = self.rng.integers(len(world))
            distance = self.rng.uniform(0.3, max(0.31, min(ranges[beam], 8.0)))
            spot = Person(f"false{self._next}", pose[0] + distance * math.cos(world[beam]),
                          pose[1] + distance * math.sin(world[beam]))
            self._next += 1
            self._false.append((spot, self.false_track_scans))
        return [person for person, _ in self._false]
