"""Shared pieces of the traffic_gp benchmarks: simulated data sets, baselines chosen on a
validation split, output of figures and JSON (artifacts/bench/)."""
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np

from traffic_gp.baselines import BinnedMean, FreMEn

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "artifacts" / "bench"
SHARED_MAPS = Path(os.environ.get("SHARED_DATA_DIR", str(ROOT.parent / "shared" / "data"))) / "maps"


def machine_note() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.node()} {os.cpu_count()} cores, load average {load:.1f} at start "
            f"(other work on the machine slows the timings)")


def maps(quick: bool) -> List[str]:
    """The generated building and, when present, real maps from ../shared/data/maps."""
    specs = ["generated:0"]
    real = sorted(SHARED_MAPS.glob("levine_*.yaml"))
    if real:
        specs.append(str(real[-1]))          # levine_6th
        if not quick and len(real) > 1:
            specs.append(str(real[0]))       # levine_4th_good
    else:
        print(f"note: no real maps under {SHARED_MAPS}; only the generated building", flush=True)
    return specs


def map_name(spec: str) -> str:
    return spec.replace(":", "_") if spec.startswith("generated") else Path(spec).stem


def split(items: Sequence, fraction: float, seed: int) -> Tuple[list, list]:
    order = np.random.default_rng(seed).permutation(len(items))
    cut = int(len(items) * (1 - fraction))
    return [items[i] for i in order[:cut]], [items[i] for i in order[cut:]]


def choose_baselines(cells, train, *, period: float = 24.0, seed: int = 0) -> Dict[str, dict]:
    """BinnedMean and FreMEn with their setting chosen on a validation split (20 % of the
    training rows), once by log-likelihood and once by squared error of the counts (whose
    expectation is the exposure-weighted squared error against the true rate plus a constant),
    then refitted on all training rows. Keys: binned_mean, fremen (log-likelihood) and
    binned_mean_mse, fremen_mse (squared error)."""
    order = np.random.default_rng(seed).permutation(len(train))
    cut = int(0.8 * len(train))
    fit_part, val_part = train.subset(order[:cut]), train.subset(order[cut:])

    def scores(model) -> Tuple[float, float]:
        pred = model.predict(val_part.x, val_part.y, val_part.t, val_part.exposure)
        return model.score(val_part), -float(np.mean((val_part.count - pred) ** 2))

    binned = {v: scores(BinnedMean(cells, bin_minutes=v, period=period).fit(fit_part))
              for v in (5, 10, 15, 20, 30, 60)}
    fremen = FreMEn(cells, period=period).fit(fit_part)      # one spectrum, orders chosen from it
    orders = {v: scores(fremen.set_order(v)) for v in (0, 1, 2, 3, 4, 6, 8, 12, 16)}
    chosen = {}
    for name, table, make in (
            ("binned_mean", binned, lambda v: BinnedMean(cells, bin_minutes=v, period=period)),
            ("fremen", orders, lambda v: FreMEn(cells, order=v, period=period))):
        for suffix, column in (("", 0), ("_mse", 1)):
            best = max(table, key=lambda v: table[v][column])
            chosen[name + suffix] = {
                "model": make(best).fit(train), "setting": best,
                "validation": {str(k): round(v[column], 6) for k, v in table.items()}}
    return chosen


def write_json(name: str, payload: dict) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    payload = dict(payload, machine=machine_note(), python=sys.version.split()[0],
                   finished=time.strftime("%Y-%m-%d %H:%M:%S"))
    path = OUT / f"{name}.json"
    path.write_text(json.dumps(payload, indent=2, default=float))
    print(f"wrote {path}", flush=True)
    return path
