#!/usr/bin/env python3
"""Crowd model quality on simulated robots' counts, against the simulator's truth and two
baselines on the same data (mean per cell and time bin; FreMEn), on the generated building and
the real maps in ../shared/data/maps.

Training: `--views` robot views over the weekdays of `--weeks` weeks (rows merged per cell and
minute). Test: views by other robots in the following week. Figures: RMSE of the expected people
per cell against the true rate (all cells of a weekday at 5-minute steps; also halls only),
held-out log-likelihood per count, and coverage of the 90% predictive interval (randomised PIT,
and plainly "count inside [5%, 95%] quantiles", which over-covers for small counts even for the
true rates), also on "busy" rows alone (true expected count >= 0.1), and the share of cells
and times whose true density lies in the GP's own 90% credible band. Baselines' settings
are chosen by validation log-likelihood on the training data.
The GP is given the map's cells (`--spatial-inputs auto`: geodesic inputs; `xy` for the kernel
on map coordinates). Writes artifacts/bench/traffic_quality.json (`--out-name`) and plots.

  python bench/traffic_gp/traffic_quality.py [--quick] [--views N] [--steps N] [--maps SPEC ...]
      [--spatial-inputs auto|xy|geodesic]
"""
import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

from traffic_gp.baselines import BinnedMean, FreMEn  # noqa: E402
from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.sim.evaluation import (  # noqa: E402
    TruthModel,
    day_times,
    heldout,
    model_counts,
    report,
    rmse,
    simulator_for,
    truth_in_band,
    weekday_views,
)

TARGET_RATIO, COVER = 0.8, (0.85, 0.95)


def run_map(spec: str, args) -> dict:
    name = tc.map_name(spec)
    print(f"\n== {name} ==", flush=True)
    sim = simulator_for(spec, args.cell_size, seed=1)
    test_sim = simulator_for(spec, args.cell_size, seed=2)
    start = time.perf_counter()
    train_views = weekday_views(sim, args.views, weeks=args.weeks)
    test_views = weekday_views(test_sim, args.test_views, weeks=1, start_week=args.weeks)
    train = Observations.from_views(sim.cells, train_views).compress(1 / 60.0, None)
    test = Observations.from_views(sim.cells, test_views)
    print(f"  {sim.cells.n_cells} cells; {len(train_views)} training views -> {len(train)} rows; "
          f"{len(test)} test rows ({time.perf_counter() - start:.0f} s)", flush=True)
    model = TrafficGP(n_inducing=args.inducing, n_steps=args.steps, progress=True,
                      spatial_inputs=args.spatial_inputs).fit(train, cells=sim.cells)
    print(f"  GP trained: {model.n_steps_} steps (best {model.best_step_}, anneal from "
          f"{model.anneal_start_}) in {model.train_seconds_:.0f} s", flush=True)
    models = {"gp": model}
    chosen = tc.choose_baselines(sim.cells, train)
    models.update({key: value["model"] for key, value in chosen.items()})
    models["truth"] = TruthModel(sim)
    times = day_times(5.0, 7 * 24.0 * args.weeks + 48.0)       # the test week's Wednesday
    truth = sim.expected_count(times)
    halls = sim.layout.hall >= 0
    result = {"cells": sim.cells.n_cells, "train_views": len(train_views), "train_rows": len(train),
              "test_rows": len(test), "train_seconds": model.train_seconds_,
              "steps": model.n_steps_, "best_step": model.best_step_,
              "anneal_start": model.anneal_start_,
              "baseline_settings": {k: v["setting"] for k, v in chosen.items()},
              "baseline_validation": {k: v["validation"] for k, v in chosen.items()}}
    busy = models["truth"].predict(test.x, test.y, test.t, test.exposure) >= 0.1
    result["busy_test_rows"] = int(busy.sum())
    for key, candidate in models.items():
        pred = model_counts(candidate, sim, times)
        scores = heldout(candidate, test, busy=busy)
        scores.update(rmse=rmse(pred, truth), rmse_halls=rmse(pred, truth, halls))
        result[key] = scores
        print(f"  {key:12s} RMSE {scores['rmse']:.4f} (halls {scores['rmse_halls']:.4f})  "
              f"log-lik {scores['loglik']:.4f}  90% coverage: PIT {scores['coverage_pit']:.3f}, "
              f"inside {scores['coverage_inside']:.3f}; on busy rows PIT "
              f"{scores.get('coverage_pit_busy', float('nan')):.3f}", flush=True)
    result["gp"]["truth_in_90_band"] = truth_in_band(model, sim, times)
    print(f"  true density inside the GP's 90% credible band: "
          f"{result['gp']['truth_in_90_band']:.3f} of cells x times", flush=True)
    baselines = [key for key in chosen]
    best = min(result[key]["rmse"] for key in baselines)
    result["ratio_to_best_baseline"] = result["gp"]["rmse"] / best
    result["ratio_to_best_baseline_halls"] = result["gp"]["rmse_halls"] / min(
        result[key]["rmse_halls"] for key in baselines)
    result["baseline_rmse_by_setting"] = rmse_by_setting(sim, train, times, truth)
    best_any = min(min(v.values()) for v in result["baseline_rmse_by_setting"].values())
    result["ratio_to_best_baseline_any_setting"] = result["gp"]["rmse"] / best_any
    print(f"  baselines' RMSE for every setting (the best picked with the truth, which real robots "
          f"cannot do): {result['baseline_rmse_by_setting']}; GP / that best: "
          f"{result['ratio_to_best_baseline_any_setting']:.2f}", flush=True)
    result["numbers"] = report(model, sim, tc.OUT, name=f"traffic_quality_{name}")
    cover = result["gp"]["coverage_pit"]
    print(f"  GP / best baseline RMSE: {result['ratio_to_best_baseline']:.2f} (target <= "
          f"{TARGET_RATIO}); halls {result['ratio_to_best_baseline_halls']:.2f}; 90% interval "
          f"coverage {cover:.3f} (target {COVER[0]}-{COVER[1]})", flush=True)
    return result


def rmse_by_setting(sim, train, times, truth) -> dict:
    """Each baseline's RMSE against the truth for each of its settings."""
    binned = {v: rmse(model_counts(BinnedMean(sim.cells, bin_minutes=v).fit(train), sim, times),
                      truth) for v in (5, 10, 15, 20, 30, 60)}
    fremen = FreMEn(sim.cells).fit(train)
    orders = {v: rmse(model_counts(fremen.set_order(v), sim, times), truth)
              for v in (0, 1, 2, 3, 4, 6, 8, 12, 16)}
    return {"binned_mean": {k: round(e, 5) for k, e in binned.items()},
            "fremen": {k: round(e, 5) for k, e in orders.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run (two maps)")
    parser.add_argument("--views", type=int)
    parser.add_argument("--test-views", type=int, default=3000)
    parser.add_argument("--weeks", type=int, default=2)
    parser.add_argument("--steps", type=int)
    parser.add_argument("--inducing", type=int, default=400)
    parser.add_argument("--cell-size", type=float, default=0.5)
    parser.add_argument("--spatial-inputs", default="auto", choices=("auto", "xy", "geodesic"),
                        help="the GP's spatial inputs (auto: geodesic, the map is known)")
    parser.add_argument("--out-name", default="traffic_quality", help="JSON file name")
    parser.add_argument("--maps", nargs="*", help="generated:SEED or .yaml files")
    args = parser.parse_args(argv)
    args.views = args.views or (5000 if args.quick else 30000)
    args.steps = args.steps or (300 if args.quick else 1500)
    if args.quick:
        args.test_views = min(args.test_views, 1000)
    print(f"traffic_quality: {tc.machine_note()}", flush=True)
    results = {tc.map_name(spec): run_map(spec, args) for spec in (args.maps or tc.maps(args.quick))}
    print("\nsummary (RMSE in people per 0.5 m cell; ratio = GP / better baseline):")
    for name, r in results.items():
        ok = r["ratio_to_best_baseline"] <= TARGET_RATIO
        cover = COVER[0] <= r["gp"]["coverage_pit"] <= COVER[1]
        binned = min(r["binned_mean"]["rmse"], r["binned_mean_mse"]["rmse"])
        fremen = min(r["fremen"]["rmse"], r["fremen_mse"]["rmse"])
        print(f"  {name:18s} GP {r['gp']['rmse']:.4f}  mean/bin {binned:.4f}  "
              f"FreMEn {fremen:.4f}  ratio {r['ratio_to_best_baseline']:.2f} "
              f"[{'ok' if ok else 'MISSED'}]  coverage {r['gp']['coverage_pit']:.3f} "
              f"[{'ok' if cover else 'MISSED'}]  log-lik GP {r['gp']['loglik']:.4f} vs "
              f"{max(r[k]['loglik'] for k in r['baseline_settings']):.4f} (truth "
              f"{r['truth']['loglik']:.4f}); vs the best baseline setting picked with the truth "
              f"{r['ratio_to_best_baseline_any_setting']:.2f}")
    tc.write_json(args.out_name, {"args": vars(args), "targets": {
        "rmse_ratio": TARGET_RATIO, "coverage": COVER}, "maps": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
