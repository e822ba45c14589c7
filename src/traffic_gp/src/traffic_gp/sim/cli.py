"""crowd_model: train a crowd model on simulated robots, plot it against the truth, inspect files.

  python -m traffic_gp.sim.cli train --map generated:0 --views 20000 --steps 1500 --out crowd.npz
  python -m traffic_gp.sim.cli train --counted --views 1500 --out crowd.npz  (a counter's counts)
  python -m traffic_gp.sim.cli report --model crowd.npz --map generated:0 --out plots/
  python -m traffic_gp.sim.cli info crowd.npz
--map takes `generated:SEED` (a generated building), `generated-loop:SEED` (the same floor with
west and north corridors round its main hall) or a map_server .yaml file (halls derived).
Part of `traffic_gp.sim`: it needs robot_sim (the people simulator). Errors: one `ERROR: ...`
line on stderr and exit status 1.
"""
import argparse
import json
import sys
import time
from pathlib import Path
from typing import List, Optional

from robot_common.errors import CommonError
from robot_sim.errors import SimError
from traffic_gp.errors import TrafficError
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_header
from traffic_gp.sim.counted import counted_views
from traffic_gp.sim.evaluation import report as make_report
from traffic_gp.sim.evaluation import simulator_for, weekday_views


def parse_args(argv: Optional[List[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="crowd_model", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    train = sub.add_parser("train", help="simulate robots' counts, fit a model, save it")
    train.add_argument("--map", default="generated:0",
                       help="generated:SEED, generated-loop:SEED or a map_server .yaml file")
    train.add_argument("--cell-size", type=float, default=0.5)
    train.add_argument("--views", type=int, default=20000, help="robot views (observations)")
    train.add_argument("--weeks", type=int, default=2, help="weeks of weekdays they span")
    train.add_argument("--robots", type=int, default=3)
    train.add_argument("--steps", type=int, default=1500)
    train.add_argument("--inducing", type=int, default=400)
    train.add_argument("--weekly", action="store_true",
                       help="model the week, not one day (default: chosen on the last days)")
    train.add_argument("--seed", type=int, default=1)
    train.add_argument("--quick", action="store_true",
                       help="no hold-out days: the default settings fitted on all rows, without "
                            "the baselines' comparison or interval calibration (a demo's minute)")
    train.add_argument("--counted", action="store_true",
                       help="learn from what a robot's people counter counts (its laser and a "
                            "tracker with 10%% misses and false tracks; traffic_gp.sim.counted) "
                            "instead of the simulator's exact counts")
    train.add_argument("--scans", type=int, default=4,
                       help="with --counted: scans per view, at 2 Hz")
    train.add_argument("--out", type=Path, required=True)
    train.add_argument("--report", type=Path, help="also write plots here")
    report = sub.add_parser("report", help="plots of a saved model against the simulator's truth")
    report.add_argument("--model", type=Path, required=True)
    report.add_argument("--map", default="")
    report.add_argument("--out", type=Path, required=True)
    info = sub.add_parser("info", help="print a saved model's header")
    info.add_argument("model", type=Path)
    return parser.parse_args(argv)


def train(args) -> dict:
    """Simulate the robots' views, fit a TrafficGP, save it; {'model', 'sim'}."""
    sim = simulator_for(args.map, args.cell_size, seed=args.seed)
    start = time.perf_counter()
    if args.counted:
        views = counted_views(sim, args.views, weeks=args.weeks, robots=args.robots,
                              scans=args.scans, seed=args.seed, progress=True)
    else:
        views = weekday_views(sim, args.views, weeks=args.weeks, robots=args.robots,
                              progress=True)
    rows = Observations.from_views(sim.cells, views).compress(1 / 60.0, None)   # time order kept
    print(f"{len(views)} views -> {len(rows)} rows (per cell and minute) in "
          f"{time.perf_counter() - start:.1f} s", flush=True)
    model = TrafficGP(n_inducing=args.inducing, n_steps=args.steps,
                      weekly=True if args.weekly else "auto", random_state=args.seed,
                      validation_fraction=0.0 if args.quick else 0.2,
                      progress=True).fit(rows, cells=sim.cells)
    meta = {"map": args.map, "cell_size": args.cell_size, "views": len(views), "seed": args.seed,
            "counts": "people counter" if args.counted else "exact"}
    model.save(args.out, meta=meta)
    print(f"trained {model.n_steps_} steps in {model.train_seconds_:.1f} s; saved {args.out}")
    print(model.status())
    return {"model": model, "sim": sim}


def report(model, sim, out: Path) -> None:
    """Plots of `model` against the simulator's truth into `out`, and the numbers shown."""
    numbers = make_report(model, sim, out, step_minutes=10.0)
    print(f"plots in {out}: crowd_maps.png, crowd_cells_over_day.png")
    for when, cells in numbers.items():
        for name, value in cells.items():
            print(f"  {when:10s} {name:14s} model {value['model']:.3f}  truth {value['truth']:.3f}"
                  "  people per cell")


def main(argv: Optional[List[str]] = None) -> int:
    args = parse_args(argv)
    try:
        if args.command == "info":
            print(json.dumps(read_header(args.model), indent=2))
        elif args.command == "train":
            result = train(args)
            if args.report:
                report(result["model"], result["sim"], args.report)
        else:
            model = TrafficGP.load(args.model)
            spec = args.map or model.meta_.get("map", "generated:0")
            report(model, simulator_for(spec, model.meta_.get("cell_size", 0.5)), args.out)
    except (TrafficError, SimError, CommonError, OSError) as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
