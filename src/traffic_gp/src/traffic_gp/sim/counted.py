"""Counts as a robot's people counter makes them, over weeks of working days, without ROS.

Robots stop at places spread over the building (mostly in the halls, as
`PeopleSimulator.observe` picks them) at times spread over the weekdays. At each stop the
robot's laser (`robot_sim.mobile_base.SensorModel`: its beams and range) and a people tracker
with misses and false tracks (`robot_sim.crowd.Tracker`) watch the people of a `Crowd` (the
simulator's densities at that time) for `scans` scans at `rate` Hz, and the people_counter
node's core (`counting.PeopleCounter` with the node's own settings, `PeopleCounterParams`)
counts them per seen cell. Each watch becomes a `View`, as the crowd model turns a
PeopleCount message into rows. What the model learns from these is what it would learn from
a robot's counter: the misses, false tracks, occlusions and laser shadows included.
"""
import math
from typing import List

import numpy as np

from robot_common.cells import View
from robot_sim.crowd import Crowd, Tracker
from robot_sim.mobile_base import SensorModel
from robot_sim.people import PeopleSimulator
from traffic_gp.counting import Detection, Scan
from traffic_gp.params import PeopleCounterParams

__all__ = ["counted_views"]


def counted_views(sim: PeopleSimulator, n_views: int, *, weeks: int = 2, robots: int = 3,
                  scans: int = 4, rate: float = 2.0, hall_share: float = 0.8,
                  miss_rate: float = 0.1, false_positive_rate: float = 0.1, seed: int = 0,
                  progress: bool = False) -> List[View]:
    """About `n_views` watches of `scans` scans each, at random weekday times of `weeks` weeks
    (see the module): the counter's counts of each, one `View` per watch that saw a cell."""
    rng = np.random.default_rng(seed)
    per_day = int(np.ceil(n_views / (weeks * 5)))
    days = np.repeat([(week * 7 + day) * 24.0 for week in range(weeks) for day in range(5)],
                     per_day)
    times = np.sort(days + rng.uniform(0.0, 24.0, days.size))[:n_views]
    places = sim.random_places(times.size, hall_share)
    laser = SensorModel(sim.cells.grid)
    crowd = Crowd(sim, seed=seed + 1)
    tracker = Tracker(miss_rate=miss_rate, false_positive_rate=false_positive_rate,
                      seed=seed + 2)
    counter = PeopleCounterParams().make_counter(sim.cells, watch=scans / rate)
    views = []
    stops = range(times.size)
    if progress:
        from tqdm import tqdm
        stops = tqdm(stops, desc="counting people at robot stops", unit="stop", mininterval=1.0)
    for i in stops:
        pose = (float(places[i, 0]), float(places[i, 1]), float(rng.uniform(-math.pi, math.pi)))
        for k in range(scans):
            hours = times[i] + k / rate / 3600.0
            crowd.advance(hours * 3600.0, hours)
            ranges, report, _ = tracker.scan(sim.cells.grid, crowd, pose, laser.scan_angles,
                                             laser.scan_range)
            counter.add(Scan(hours * 3600.0, pose, laser.scan_angles, ranges, 0.0,
                             laser.scan_range), [Detection(p.name, p.x, p.y) for p in report])
        watch = counter.flush()
        if watch is not None and len(watch.cells):
            views.append(View(f"robot_{i % robots}", watch.start / 3600.0, watch.x, watch.y,
                              watch.duration, watch.cells, watch.fractions, watch.counts))
    return views
