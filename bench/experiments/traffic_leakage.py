#!/usr/bin/env python3
"""Wall leakage of the crowd model: how much of the busiest hall's crowd the GP puts into the
rooms beside it, on a people simulator where nobody is outside the halls (`room_busy=0`), for
the spatial kernel on map coordinates (`spatial_inputs="xy"`) and on the geodesic embedding of
the map (`"geodesic"`), trained on the same rows.

Training: `--views` robot views over the weekdays of `--weeks` weeks, `--hall-share` of them
from hall cells (1.0: robots watch the halls only, rooms are seen through doors at most).
Figures per map and variant (`sim.evaluation.wall_leakage`, the test week's Wednesday at
5-minute steps): leakage = mean predicted count in the cells within 1.5 m (through walls) of a
main-hall cell and outside every hall / mean true count in the main hall (target < 5 %), the
worst such cell, and the RMSE of the expected people per cell against the truth.
With `--doors-closed` every door of the generated building is shut: the rooms are cells the
people cannot reach from the halls (the case the geodesic inputs are for); with the doors open
the rooms' cells beside the main hall are 0.5-3.2 m from it through the doors.
Writes artifacts/bench/traffic_leakage_doors_<open|closed>_hall_share_<share>.json.

  python bench/experiments/traffic_leakage.py [--quick] [--views N] [--steps N] [--hall-share S]
      [--doors-closed] [--maps SPEC ...]
"""
import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "traffic_gp"))
import traffic_common as tc  # noqa: E402

from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.sim.evaluation import (  # noqa: E402
    day_times,
    model_counts,
    rmse,
    simulator_for,
    wall_leakage,
    weekday_views,
)

TARGET = 0.05
VARIANTS = ("xy", "geodesic")


def run_map(spec: str, args) -> dict:
    name = tc.map_name(spec)
    print(f"\n== {name} ==", flush=True)
    sim = simulator_for(spec, args.cell_size, seed=1, room_busy=0.0,
                        doors_closed=args.doors_closed)
    views = weekday_views(sim, args.views, weeks=args.weeks, hall_share=args.hall_share)
    train = Observations.from_views(sim.cells, views).compress(1 / 60.0, None)
    times = day_times(5.0, 7 * 24.0 * args.weeks + 48.0)
    truth = sim.expected_count(times)
    result = {"cells": sim.cells.n_cells, "train_views": len(views), "train_rows": len(train)}
    print(f"  {sim.cells.n_cells} cells; {len(views)} views -> {len(train)} rows", flush=True)
    for variant in VARIANTS:
        start = time.perf_counter()
        model = TrafficGP(n_inducing=args.inducing, n_steps=args.steps, spatial_inputs=variant,
                          random_state=args.seed).fit(train, cells=sim.cells)
        scores = wall_leakage(model, sim, times)
        scores.update(rmse=rmse(model_counts(model, sim, times), truth), steps=model.n_steps_,
                      seconds=time.perf_counter() - start)
        result[variant] = scores
        print(f"  {variant:9s} leakage {scores['leakage']:.3f} of the hall rate (worst cell "
              f"{scores['leakage_max_cell']:.3f}; {scores['beside_cells']} cells beside "
              f"{scores['main_cells']} main-hall cells); hall predicted/true "
              f"{scores['hall_ratio']:.2f}; RMSE {scores['rmse']:.4f}; {scores['steps']} steps "
              f"in {scores['seconds']:.0f} s", flush=True)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small run (the generated map)")
    parser.add_argument("--views", type=int)
    parser.add_argument("--weeks", type=int, default=2)
    parser.add_argument("--steps", type=int)
    parser.add_argument("--inducing", type=int, default=400)
    parser.add_argument("--hall-share", type=float, default=1.0)
    parser.add_argument("--doors-closed", action="store_true",
                        help="generated buildings with every door shut (rooms unreachable)")
    parser.add_argument("--cell-size", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--maps", nargs="*", help="generated:SEED or .yaml files")
    args = parser.parse_args(argv)
    args.views = args.views or (3000 if args.quick else 20000)
    args.steps = args.steps or (300 if args.quick else 1500)
    print(f"traffic_leakage: {tc.machine_note()}", flush=True)
    specs = args.maps or (["generated:0"] if args.quick else tc.maps(False))
    results = {tc.map_name(spec): run_map(spec, args) for spec in specs}
    print(f"\nsummary (leakage = predicted beside the main hall / true main-hall rate; target < "
          f"{TARGET:.0%}):")
    for name, r in results.items():
        cells = "  ".join(f"{v} {r[v]['leakage']:.3f} "
                          f"[{'ok' if r[v]['leakage'] < TARGET else 'MISSED'}] RMSE "
                          f"{r[v]['rmse']:.4f}" for v in VARIANTS)
        print(f"  {name:18s} {cells}")
    doors = "closed" if args.doors_closed else "open"
    tc.write_json(f"traffic_leakage_doors_{doors}_hall_share_{args.hall_share:g}",
                  {"args": vars(args), "target": TARGET, "maps": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
