#!/usr/bin/env python3
"""Costs of the crowd model: training time against the number of observations (robot views),
whole-map prediction time at one time, load time of a saved model, and how each grows as the
cells get finer. Targets: 100,000 observations trained in < 5 min, whole-map prediction < 0.5 s,
load < 2 s. Writes artifacts/bench/traffic_cost.json and plots.

An observation is one robot view (one PeopleCount message, ~50-100 seen cells); it becomes one
row per seen cell, and rows are merged per cell and minute of the day (exact for Poisson counts)
before training. Training time = converting and merging the rows + `--steps` SVGP steps; the
simulation that makes the views is reported apart.

  python bench/traffic_gp/traffic_cost.py [--quick] [--steps N]
"""
import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

import traffic_gp.plots as plots  # noqa: E402
from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.posterior import PosteriorSnapshot  # noqa: E402
from traffic_gp.queries import CrowdQueries  # noqa: E402
from traffic_gp.sim.evaluation import day_times, model_counts, rmse, simulator_for, weekday_views  # noqa: E402


def timed(function, repeat: int = 5) -> float:
    """Median seconds of `repeat` calls (after one warm-up call)."""
    function()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def training_runs(sizes, steps: int) -> list:
    sim = simulator_for("generated:0", 0.5, seed=1)
    truth_times = day_times(10.0)
    truth = sim.expected_count(truth_times)
    runs = []
    for size in sizes:
        start = time.perf_counter()
        views = weekday_views(sim, size, weeks=4, progress=size >= 50000)
        simulated = time.perf_counter() - start
        start = time.perf_counter()
        rows = Observations.from_views(sim.cells, views)
        merged = rows.compress(1 / 60.0, None)
        prepared = time.perf_counter() - start
        model = TrafficGP(n_steps=steps, progress=True).fit(merged)
        total = prepared + model.train_seconds_
        per_step = (model.train_seconds_ - model.compile_seconds_) / max(steps - 1, 1)
        error = rmse(model_counts(model, sim, truth_times), truth)
        runs.append({"views": size, "cell_rows": len(rows), "merged_rows": len(merged),
                     "simulate_s": simulated, "prepare_s": prepared,
                     "fit_s": model.train_seconds_, "compile_s": model.compile_seconds_,
                     "train_total_s": total, "s_per_step": per_step, "rmse": error})
        print(f"  {size:7d} views ({len(rows)} cell rows -> {len(merged)} merged): prepare "
              f"{prepared:.1f} s + fit {model.train_seconds_:.1f} s (of which compiling "
              f"{model.compile_seconds_:.1f} s) = {total:.1f} s ({per_step * 1000:.0f} ms/step); "
              f"RMSE {error:.4f}; simulation {simulated:.1f} s", flush=True)
        del rows, views
    return runs


def cold_load_seconds(path: Path, loader: str) -> float:
    """Load and answer one prediction in a fresh process, imports included: `TrafficGP` (the
    trainable model: TensorFlow and GPflow) or `PosteriorSnapshot` (NumPy, what the node serves
    from at start)."""
    module = "traffic_gp.model" if loader == "TrafficGP" else "traffic_gp.posterior"
    code = (f"import time; t = time.perf_counter(); from {module} import {loader}; "
            f"{loader}.load({str(path)!r}).predict(10.0, 6.5, 58.8); print(time.perf_counter() - t)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def cell_size_runs(sizes, steps: int) -> list:
    runs = []
    for cell_size in sizes:
        sim = simulator_for("generated:0", cell_size, seed=1)
        rows = Observations.from_views(sim.cells, weekday_views(sim, 3000, weeks=1))
        merged = rows.compress(1 / 60.0, None)
        model = TrafficGP(n_steps=steps).fit(merged)
        queries = CrowdQueries(model, sim.cells)
        predict = timed(lambda q=queries: q.densities([58.8]))
        costmaps = timed(lambda q=queries: q.cost_grid(58.8, lookahead_hours=0.5, step_hours=5 / 60,
                                                   saturation_density=1.0), repeat=3)
        path = tc.OUT / f"traffic_cost_model_{cell_size}.npz"
        model.save(path)
        load = timed(lambda p=path: TrafficGP.load(p), repeat=3)
        snapshot_load = timed(lambda p=path: PosteriorSnapshot.load(p), repeat=3)
        snapshot = CrowdQueries(PosteriorSnapshot.load(path), sim.cells)
        snapshot_predict = timed(lambda q=snapshot: q.densities([58.8]))
        per_step = (model.train_seconds_ - model.compile_seconds_) / max(steps - 1, 1)
        runs.append({"cell_size": sim.cells.cell_size, "cells": sim.cells.n_cells,
                     "merged_rows": len(merged), "s_per_step": per_step,
                     "predict_map_s": predict, "costmaps_s": costmaps, "load_s": load,
                     "numpy_load_s": snapshot_load, "numpy_predict_map_s": snapshot_predict,
                     "file_mb": path.stat().st_size / 1e6})
        print(f"  cells {sim.cells.cell_size:.3f} m: {sim.cells.n_cells:6d} cells, "
              f"{len(merged)} rows, {per_step * 1000:.0f} ms/step, "
              f"whole-map prediction {predict * 1000:.0f} ms, both cost maps (7 times, full "
              f"resolution) {costmaps * 1000:.0f} ms, load {load:.2f} s "
              f"({path.stat().st_size / 1e6:.1f} MB with data); NumPy posterior: load "
              f"{snapshot_load:.2f} s, whole-map prediction {snapshot_predict * 1000:.0f} ms",
              flush=True)
    return runs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run")
    parser.add_argument("--steps", type=int, help="SVGP steps per fit (default 1500; quick 100)")
    args = parser.parse_args(argv)
    steps = args.steps or (100 if args.quick else 1500)
    sizes = [1000, 10000] if args.quick else [1000, 10000, 100000]
    cell_sizes = [1.0, 0.5] if args.quick else [1.0, 0.5, 0.25, 0.125]
    print(f"traffic_cost: {tc.machine_note()}", flush=True)
    print(f"training time against observations ({steps} steps each):", flush=True)
    training = training_runs(sizes, steps)
    print("growth with finer cells (generated building, 3000 views, 50 steps):", flush=True)
    cells = cell_size_runs(cell_sizes, 50)
    cold = cold_load_seconds(tc.OUT / "traffic_cost_model_0.5.npz", "TrafficGP")
    cold_numpy = cold_load_seconds(tc.OUT / "traffic_cost_model_0.5.npz", "PosteriorSnapshot")
    at_05 = next(run for run in cells if abs(run["cell_size"] - 0.5) < 1e-6)
    biggest = training[-1]
    print("\nsummary against the targets:")
    print(f"  train {biggest['views']} observations: {biggest['train_total_s']:.0f} s "
          f"(target < 300 s for 100,000) [{'ok' if biggest['train_total_s'] < 300 else 'MISSED'}]")
    print(f"  whole-map prediction (0.5 m cells, {at_05['cells']} cells): "
          f"{at_05['predict_map_s'] * 1000:.0f} ms (target < 500 ms) "
          f"[{'ok' if at_05['predict_map_s'] < 0.5 else 'MISSED'}]")
    print(f"  load a saved model and answer, in a fresh process, imports included (target < 2 s): "
          f"NumPy posterior (what the node serves from at start) {cold_numpy:.2f} s "
          f"[{'ok' if cold_numpy < 2 else 'MISSED'}]; trainable GPflow model {cold:.1f} s (most of "
          f"it importing TensorFlow; {at_05['load_s']:.2f} s once TensorFlow is imported)")
    plots.lines({"train": [r["views"] for r in training]},
                {"train": [r["train_total_s"] for r in training]}, tc.OUT / "traffic_cost_train.png",
                xlabel="observations (robot views)", ylabel="seconds", logx=True,
                title=f"training time ({steps} steps)")
    plots.lines({k: [r["cells"] for r in cells] for k in ("predict", "load")},
                {"predict": [r["predict_map_s"] for r in cells], "load": [r["load_s"] for r in cells]},
                tc.OUT / "traffic_cost_cells.png", xlabel="cells", ylabel="seconds", logx=True,
                logy=True, title="whole-map prediction and load time vs cells")
    tc.write_json("traffic_cost", {"steps": steps, "training": training, "cell_sizes": cells,
                                   "cold_load_s": cold, "cold_load_numpy_s": cold_numpy,
                                   "targets": {"train_100k_s": 300, "predict_s": 0.5, "load_s": 2}})
    return 0


if __name__ == "__main__":
    sys.exit(main())
