#!/usr/bin/env python3
"""Does the crowd model's weekly term pay? The GP with one cyclic day against the GP with the
week (`weekly=True`) and the week-periodic baselines, on robots that also work at weekends.

The simulator's weekends are quiet (a quarter of a weekday's activity, no class rushes). Training:
`--views` views spread over all seven days of `--weeks` weeks; test: other robots' views in the
following week. Figures: RMSE of the expected people per cell against the true rate over that
week's Wednesday and Saturday (5-minute steps) and held-out log-likelihood per count.
Writes artifacts/bench/traffic_weekly.json. The full run takes about 20 minutes here and up to
11 GB of memory (choosing the week-periodic baselines' settings on 2.8 M rows); --quick, 3 minutes.

  python bench/experiments/traffic_weekly.py [--quick] [--views N] [--steps N] [--map SPEC]
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
    TruthModel,
    day_times,
    heldout,
    model_counts,
    rmse,
    simulator_for,
)

WEEK = 168.0
DAYS = {"Wednesday": 2, "Saturday": 5}


def whole_week_views(sim, n_views: int, *, weeks: int, start_week: int = 0) -> list:
    """About `n_views` views over all days of `weeks` weeks from `start_week` (3 robots)."""
    per_week = -(-n_views // weeks)
    views = []
    for week in range(start_week, start_week + weeks):
        views += sim.observe(per_week, robots=3, start=week * WEEK, hours=WEEK, radius=4.0)
    return views[:n_views]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run")
    parser.add_argument("--views", type=int)
    parser.add_argument("--test-views", type=int, default=3000)
    parser.add_argument("--weeks", type=int, default=3)
    parser.add_argument("--steps", type=int)
    parser.add_argument("--map", default="generated:0", help="generated:SEED or a .yaml file")
    args = parser.parse_args(argv)
    args.views = args.views or (6000 if args.quick else 40000)
    args.steps = args.steps or (300 if args.quick else 1500)
    print(f"traffic_weekly: {tc.machine_note()}", flush=True)

    sim, test_sim = simulator_for(args.map, 0.5, seed=1), simulator_for(args.map, 0.5, seed=2)
    train = Observations.from_views(sim.cells, whole_week_views(sim, args.views, weeks=args.weeks))
    train = train.compress(1 / 60.0, WEEK)
    test = Observations.from_views(sim.cells, whole_week_views(
        test_sim, args.test_views, weeks=1, start_week=args.weeks))
    print(f"  {tc.map_name(args.map)}: {sim.cells.n_cells} cells, {len(train)} training rows, "
          f"{len(test)} test rows", flush=True)

    models = {}
    for name, weekly in (("gp_daily", False), ("gp_weekly", True)):
        started = time.perf_counter()
        models[name] = TrafficGP(weekly=weekly, n_steps=args.steps, progress=True).fit(train)
        print(f"  {name}: trained in {time.perf_counter() - started:.0f} s", flush=True)
    chosen = tc.choose_baselines(sim.cells, train, period=WEEK)
    models.update({key: chosen[key]["model"] for key in ("binned_mean", "fremen")})
    models["truth"] = TruthModel(sim)

    result = {"args": vars(args), "train_rows": len(train), "test_rows": len(test),
              "baseline_settings": {k: chosen[k]["setting"] for k in ("binned_mean", "fremen")}}
    test_week = args.weeks * WEEK
    for key, model in models.items():
        scores = {"loglik": heldout(model, test)["loglik"]}
        for day, index in DAYS.items():
            times = day_times(5.0, test_week + index * 24.0)
            scores[f"rmse_{day}"] = rmse(model_counts(model, sim, times), sim.expected_count(times))
        result[key] = scores
        print(f"  {key:12s} RMSE Wednesday {scores['rmse_Wednesday']:.4f}  Saturday "
              f"{scores['rmse_Saturday']:.4f}  held-out log-lik {scores['loglik']:.4f}", flush=True)
    daily, weekly = result["gp_daily"], result["gp_weekly"]
    print(f"\nweekly / daily GP RMSE: Wednesday {weekly['rmse_Wednesday'] / daily['rmse_Wednesday']:.2f}, "
          f"Saturday {weekly['rmse_Saturday'] / daily['rmse_Saturday']:.2f}; log-lik "
          f"{weekly['loglik']:.4f} vs {daily['loglik']:.4f} (truth {result['truth']['loglik']:.4f})")
    tc.write_json("traffic_weekly", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
