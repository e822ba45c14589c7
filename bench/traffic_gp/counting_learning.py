#!/usr/bin/env python3
"""Does the crowd model learn as well from a robot's people counter as from exact counts?

One hour (simulated, in one process: the counter's core `counting.PeopleCounter`, robot_sim's
`crowd.Crowd` and `crowd.Tracker` with 10% misses and 10% false tracks, the robot patrolling
the generated building's main hall; scans at --rate Hz, Wednesday 10:00-11:00 by default) gives
two sets of rows over the same cells, times and exposures:
  counter  the counter's counts of its watches;
  exact    the simulator's exact counts there: Poisson(true density x exposure), as people_sim
           draws them.
The same TrafficGP (fixed settings, `--steps` steps) is fitted on each; its expected counts per
0.5 m cell over the hour are compared with the simulator's truth on the cells the robot saw
(RMSE). Target: the counter's RMSE within 10% of the exact counts' (ratio 0.9-1.1). Writes
artifacts/bench/counting_learning.json.

  python bench/traffic_gp/counting_learning.py [--hours 1] [--rate 5] [--steps 400]
"""
import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

from robot_common.cells import exposure  # noqa: E402
from robot_sim import generate_building  # noqa: E402
from robot_sim.crowd import Crowd, Tracker  # noqa: E402
from robot_sim.mobile_base import SensorModel, hall_patrol  # noqa: E402
from robot_sim.people import PeopleSimulator  # noqa: E402
from traffic_gp.counting import Detection, PeopleCounter, Scan  # noqa: E402
from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402

START_HOUR = 58.0         # Wednesday 10:00


def simulate(args):
    """(counter rows, exact rows, simulator) of `args.hours` of patrolling."""
    building = generate_building(0)
    sim = PeopleSimulator.from_building(building, 0.5, seed=1)
    crowd, tracker = Crowd(sim, seed=1), Tracker(seed=2)
    path, sensors = hall_patrol(building, 0.5), SensorModel(building.grid)
    counter = PeopleCounter(sim.cells, watch=10.0)
    rng = np.random.default_rng(3)
    counter_rows, exact_rows = [], []
    steps = int(args.hours * 3600 * args.rate)
    for step in range(steps + 1):
        seconds = step / args.rate
        state = path.state(seconds)
        pose = (state.x + 0.1 * math.cos(state.yaw), state.y + 0.1 * math.sin(state.yaw), state.yaw)
        crowd.advance(seconds, START_HOUR + seconds / 3600.0)
        ranges, report, _ = tracker.scan(building.grid, crowd, pose, sensors.scan_angles,
                                         sensors.scan_range)
        scan = Scan(seconds, pose, sensors.scan_angles, ranges, 0.05, sensors.scan_range)
        watch = counter.add(scan, [Detection(p.name, p.x, p.y) for p in report])
        if watch is None and step == steps:
            watch = counter.flush()
        if watch is not None and len(watch.cells):
            hours = START_HOUR + watch.start / 3600.0
            expo = exposure(watch.fractions * sim.cells.cell_area, watch.duration)
            truth = sim.density_at(hours + watch.duration / 7200.0, watch.cells) * expo
            x, y, t = sim.cells.x[watch.cells], sim.cells.y[watch.cells], np.full(len(expo), hours)
            counter_rows.append(Observations(x, y, t, expo, watch.counts))
            exact_rows.append(Observations(x, y, t, expo, rng.poisson(truth)))
        if step % int(600 * args.rate) == 0:
            print(f"  simulated {seconds / 60:.0f} of {args.hours * 60:.0f} min", flush=True)
    return Observations.concat(counter_rows), Observations.concat(exact_rows), sim


def learned_rmse(rows: Observations, sim, seen: np.ndarray, args) -> float:
    model = TrafficGP(n_inducing=100, n_steps=args.steps, likelihood="poisson", profile="none",
                      spatial_inputs="xy", hourly=False, weekly=False, validation_fraction=0.0,
                      refit_steps=0, random_state=0).fit(rows.compress(1 / 60.0, None), cells=sim.cells)
    times = START_HOUR + (np.arange(6) + 0.5) / 6.0 * args.hours
    errors = []
    for hours in times:
        pred = model.predict(sim.cells.x[seen], sim.cells.y[seen], np.full(seen.size, hours),
                             sim.cells.cell_area)
        errors.append(pred - sim.expected_count(hours, seen)[0])
    return float(np.sqrt(np.mean(np.square(errors))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--steps", type=int, default=400)
    args = parser.parse_args()
    start = time.process_time()
    counted, exact, sim = simulate(args)
    seen = np.unique(sim.cells.index_at(counted.x, counted.y))
    print(f"{len(counted)} rows over {seen.size} cells; people counted {counted.count.sum():.0f}, "
          f"exact counts {exact.count.sum():.0f} ({time.process_time() - start:.0f} CPU-s)")
    figures = {"rows": len(counted), "cells": int(seen.size), "hours": args.hours,
               "rate_hz": args.rate, "counted_people": float(counted.count.sum()),
               "exact_people": float(exact.count.sum()),
               "rmse_counter": learned_rmse(counted, sim, seen, args),
               "rmse_exact": learned_rmse(exact, sim, seen, args),
               "cpu_s": time.process_time() - start, "machine": tc.machine_note()}
    figures["ratio"] = figures["rmse_counter"] / figures["rmse_exact"]
    print(f"RMSE per cell against the truth: from the counter {figures['rmse_counter']:.4f}, from "
          f"exact counts {figures['rmse_exact']:.4f}: ratio {figures['ratio']:.3f} "
          f"(target 0.9-1.1)")
    tc.write_json("counting_learning", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
