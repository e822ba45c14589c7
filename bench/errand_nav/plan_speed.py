#!/usr/bin/env python3
"""CPU of one crowd-aware plan on a large floor: 100 m x 60 m (0.05 m map cells), halls 4 m
wide every 10 m both ways between 6 m x 6 m blocks, a forecast of 8 grids (0.5 m cells, every
2 minutes over the 15-minute look-ahead) of random densities 0-1 person/m^2 (the hardest case
for A*: no corridor is free); three errands across the floor, each planned on the crowd forecast
and on a quiet one, at 0.25 m and 0.2 m search cells. Target: well under 1 s of CPU per plan.
Prints CPU seconds (process time) per plan and of preparing the map once.

  python bench/errand_nav/plan_speed.py [--quick]
"""
import argparse
import statistics
import sys
import time

import numpy as np

from errand_nav.forecast import DensityForecast
from errand_nav.planning import CrowdPlanner, PlannerSettings
from robot_common.maps import FREE, OCCUPIED, GridMap

ERRANDS = (((2.0, 2.0), (92.0, 52.0)), ((2.0, 52.0), (92.0, 2.0)), ((52.0, 2.0), (52.0, 52.0)))


def large_floor(resolution: float = 0.05) -> GridMap:
    cells = np.full((int(60 / resolution), int(100 / resolution)), OCCUPIED, np.int8)
    cells[int(0.2 / resolution):int(59.8 / resolution), int(0.2 / resolution):int(99.8 / resolution)] = FREE
    for x in np.arange(4.0, 100.0, 10.0):
        for y in np.arange(4.0, 60.0, 10.0):
            cells[int(y / resolution):int((y + 6) / resolution),
                  int(x / resolution):int((x + 6) / resolution)] = OCCUPIED
    return GridMap(cells, resolution)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.25 m cells only, one repeat")
    args = parser.parse_args(argv)
    grid = large_floor()
    rng = np.random.default_rng(0)
    crowd = DensityForecast((0.0, 0.0), 0.5, 1000.0 + np.arange(0, 901, 120.0)[:8],
                            rng.uniform(0.0, 1.0, (8, 120, 200)))
    quiet = DensityForecast.quiet(grid)
    print("| search cell | map prepared once, CPU s | plan on the crowd forecast, CPU s (median, max) "
          "| plan on a quiet forecast, CPU s (median, max) | free search cells |")
    print("|---|---|---|---|---|")
    for cell in (0.25,) if args.quick else (0.25, 0.2):
        began = time.process_time()
        planner = CrowdPlanner(grid, PlannerSettings(cell_size=cell))
        prepared = time.process_time() - began
        figures = {}
        for name, forecast in (("crowd", crowd), ("quiet", quiet)):
            seconds = []
            for _ in range(1 if args.quick else 3):
                for start, goal in ERRANDS:
                    began = time.process_time()
                    planner.plan(start, goal, 1000.0, forecast)
                    seconds.append(time.process_time() - began)
            figures[name] = f"{statistics.median(seconds):.2f}, {max(seconds):.2f}"
            print(f"  {cell} m cells, {name}: {len(seconds)} plans", file=sys.stderr, flush=True)
        print(f"| {cell} m | {prepared:.2f} | {figures['crowd']} | {figures['quiet']} | "
              f"{int(planner.search.passable.sum())} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
