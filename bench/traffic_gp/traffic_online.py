#!/usr/bin/env python3
"""How soon the crowd node answers, and what it serves in the end, per training size.

The node (`traffic_gp.learning.Learner`) serves the tuned baselines (`quick.BaselineForecast`)
as soon as its first rows are in and chooses and fits the GP (`TrafficGP.fit` with the node's
defaults: the shipped TrafficGP parameters, at most `initial_steps` = 600 steps) in the
background; new rows are folded into what is served at once. This bench runs those same steps
in one process on N training rows of each data set (N = 10k, 40k, 80k by default; the most
recent N of the real counts, a random N of every day of the simulated ones) and prints, per size:
  first s    wall seconds to the first forecast (the baselines tuned, calibrated and fitted);
  final s    wall seconds to the final model (the GP's choice of settings, its fit, the
             baselines' comparison and the calibration), CPU seconds (user+sys) beside it;
  fold-in s  wall seconds to fold 1,000 new rows into the served baselines, and into the
             final model with its online steps (`partial_fit`; the node does the same);
  ratio      test RMSE of the final model / the best tuned baseline (FreMEn or binned mean,
             tuned by `traffic_real.tuned_baselines` on the same rows), and of the baselines
             served first;
  coverage   share of the test counts inside the 90% intervals (and by the randomised PIT),
             of the final model and of the first forecast.
Data sets as in `traffic_real.py` (akl: Auckland pedestrian counts, bench/requirements-bench.txt;
sim:<map>: simulated robots, RMSE against the simulator's truth). Targets: first forecast
<= 30 s, final model at 80k rows <= 180 s on 2 cores, ratio <= 0.9 (never above 1.0), coverage
85-95%. Writes artifacts/bench/traffic_online.json and prints a markdown table.

  python bench/traffic_gp/traffic_online.py [--sets akl,sim:generated:0] [--sizes 10000,40000,80000]
      [--out-name NAME]
"""
import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402
import traffic_real as tr  # noqa: E402

from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.quick import BaselineForecast  # noqa: E402

NODE_STEPS = 600          # the node's initial_steps default
FOLD_ROWS = 1000


def cpu() -> float:
    times = os.times()
    return times.user + times.system


def sized(rows: Observations, n: int, recent: bool) -> Observations:
    """`n` of the rows in time order (all when fewer): the most recent ones (a node that has
    run for a shorter time), or a random share of every day (a smaller fleet)."""
    order = np.argsort(rows.t, kind="stable")
    if len(rows) > n:
        order = order[-n:] if recent else np.sort(
            np.random.default_rng(0).choice(order, n, replace=False))
        order = order[np.argsort(rows.t[order], kind="stable")]
    return rows.subset(order)


def run_size(data: dict, n: int) -> dict:
    train, test = sized(data["train"], n, data["truth"] is None), data["test"]
    target = data["truth"] if data["truth"] is not None else test.count
    fold, train = train.subset(np.arange(len(train) - FOLD_ROWS, len(train))), \
        train.subset(np.arange(len(train) - FOLD_ROWS))       # the newest rows come later

    def rmse(model) -> float:
        pred = model.predict(test.x, test.y, test.t, test.exposure)
        return float(np.sqrt(np.mean((pred - target) ** 2)))

    out = {"rows": len(train) + FOLD_ROWS}
    began, used = time.perf_counter(), cpu()
    quick = BaselineForecast().fit(train, data["cells"])
    out["first_s"], out["first_cpu"] = time.perf_counter() - began, cpu() - used
    began, used = time.perf_counter(), cpu()
    gp = TrafficGP().fit(train, n_steps=NODE_STEPS, cells=data["cells"])
    out["final_s"], out["final_cpu"] = time.perf_counter() - began, cpu() - used
    began = time.perf_counter()
    quick.partial_fit(fold)
    out["fold_quick_s"] = time.perf_counter() - began
    began = time.perf_counter()
    gp.partial_fit(fold)
    out["fold_gp_s"] = time.perf_counter() - began
    baselines = tr.tuned_baselines(dict(data, train=Observations.concat([train, fold])))
    best = min(rmse(b["model"]) for b in baselines.values())
    out["ratio"], out["quick_ratio"] = rmse(gp) / best, rmse(quick) / best
    out["coverage"], out["quick_coverage"] = tr.coverage(gp, test), tr.coverage(quick, test)
    out["status"] = gp.status()
    print(f"  {out['rows']} rows: first forecast {out['first_s']:.1f} s, final model "
          f"{out['final_s']:.0f} s ({out['final_cpu']:.0f} CPU-s), fold-in of {FOLD_ROWS} rows "
          f"{out['fold_quick_s']:.2f} s / {out['fold_gp_s']:.1f} s; RMSE / best baseline "
          f"{out['ratio']:.3f} (first {out['quick_ratio']:.3f}); 90% coverage "
          f"{out['coverage']} (first {out['quick_coverage']})\n    {out['status']}", flush=True)
    return out


def table(results: dict) -> str:
    lines = ["| data set | rows | first forecast s | final model s (CPU-s) | fold-in of 1,000 "
             "rows s: baselines / GP | RMSE / best baseline: final (first) | 90% coverage on "
             "test: inside / PIT, final (first) |", "|---|---|---|---|---|---|---|"]
    for name, sizes in results.items():
        for r in sizes.values():
            c, q = r["coverage"], r["quick_coverage"]
            lines.append(
                f"| {name} | {r['rows']} | {r['first_s']:.1f} | {r['final_s']:.0f} "
                f"({r['final_cpu']:.0f}) | {r['fold_quick_s']:.2f} / {r['fold_gp_s']:.1f} | "
                f"**{r['ratio']:.2f}** ({r['quick_ratio']:.2f}) | **{c['inside']:.3f}** / "
                f"{c['pit']:.3f} ({q['inside']:.3f} / {q['pit']:.3f}) |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", default="akl", help="comma-separated: akl, sim:generated:0, "
                                                      "sim:<map .yaml>")
    parser.add_argument("--sizes", default="10000,40000,80000")
    parser.add_argument("--out-name", default="traffic_online", help="JSON file name")
    args = parser.parse_args(argv)
    sizes = [int(v) for v in args.sizes.split(",") if v]
    print(f"traffic_online: {tc.machine_note()}", flush=True)
    results = {}
    for name in [s for s in args.sets.split(",") if s]:
        data = tr.akl_set(False) if name == "akl" else tr.sim_set(name[4:], False)
        label = name if name == "akl" else "sim " + tc.map_name(name[4:])
        print(f"\n== {label}: {len(data['train'])} training rows, {len(data['test'])} test rows "
              f"({data['source']})", flush=True)
        results[label] = {}
        for n in sizes:
            results[label][str(n)] = run_size(data, n)
            tc.write_json(args.out_name, {"sets": results, "table": table(results)})
    print("\n" + table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
