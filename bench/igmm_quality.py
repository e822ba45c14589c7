#!/usr/bin/env python3
"""Quality of the object layers' IncrementalGMM on synthetic scenes with known truth, against
scikit-learn's GaussianMixture (K chosen by BIC) and BayesianGaussianMixture on the same data.

    python bench/igmm_quality.py [--quick] [--scenes N] [--orders N]

Scenes (robot_sim.detections): objects placed uniformly at least `min_separation` apart, a
Poisson number of detections per object with Gaussian noise, uniform clutter making up a share of
all detections, everything in a random order. BIC searches K = 1 .. 1.5 K_true + 3;
BayesianGaussianMixture (Dirichlet process, as many components) gets the IGMM's prior knowledge
(covariance prior sigma_ini^2 I). Every method reports the components that explain at
least 3 detections (IGMM: support >= sp_min = 3; sklearn: weight * n >= 3). Scores per scene:
count error |K_found - K_true|, OSPA (cut-off 1 m, order 1), precision and recall of a one-to-one
matching within 0.5 m; and the spread (max - min, std) of the number of clusters over random
orders of the same detections. Targets (10% clutter): precision and recall >= 0.95, OSPA <= 0.2 m,
zero spread in batch mode.
Writes artifacts/bench/igmm_quality.json and igmm_quality.png.
"""
import argparse
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from igmm_layers import LayerParams
from igmm_layers.sim.metrics import match_scores, ospa
from robot_sim.detections import random_scene, simulate_detections

OUT_DIR = Path(__file__).resolve().parent.parent / "artifacts" / "bench"
MIN_SUPPORT = 3.0
SCENARIOS = {
    "standard, no clutter": dict(objects=10, size=20.0, separation=1.5, rate=20, noise=0.1, clutter=0.0),
    "standard, 10% clutter": dict(objects=10, size=20.0, separation=1.5, rate=20, noise=0.1, clutter=0.1),
    "dense, 10% clutter": dict(objects=25, size=20.0, separation=1.0, rate=10, noise=0.15, clutter=0.1),
}
TARGET = "standard, 10% clutter"


def make_scene(spec, seed):
    scene = random_scene(spec["objects"], bounds=[(0, spec["size"])] * 2,
                         min_separation=spec["separation"], random_state=seed)
    dets = simulate_detections(scene, mean_detections=spec["rate"], noise_std=spec["noise"],
                               clutter_fraction=spec["clutter"], random_state=10000 + seed)
    return np.array([obj.position for obj in scene]), dets.positions


def igmm(X, spec, batch):
    params = LayerParams(region_size=spec["size"], batch=batch)  # the layer server's defaults
    model = params.estimator().fit(X)
    return model.means_[model.confirmed_]


def gmm_bic(X, spec, seed):
    from sklearn.mixture import GaussianMixture

    best, best_bic = None, np.inf
    for k in range(1, int(1.5 * spec["objects"]) + 4):  # up to 1.5 K_true + 3
        model = GaussianMixture(k, covariance_type="full", random_state=seed, reg_covar=1e-4,
                                max_iter=100).fit(X)
        bic = model.bic(X)
        if bic < best_bic:
            best, best_bic = model, bic
    return best.means_[best.weights_ * len(X) >= MIN_SUPPORT]


def bgmm(X, spec, seed):
    from sklearn.mixture import BayesianGaussianMixture

    # the same prior knowledge the IGMM has: cluster spread about sigma_ini = 0.01 * region size
    sigma = 0.01 * spec["size"]
    model = BayesianGaussianMixture(n_components=int(1.5 * spec["objects"]) + 3, covariance_type="full",
                                    weight_concentration_prior_type="dirichlet_process",
                                    covariance_prior=sigma ** 2 * np.eye(2), degrees_of_freedom_prior=2.0,
                                    max_iter=500, random_state=seed, reg_covar=1e-4).fit(X)
    return model.means_[model.weights_ * len(X) >= MIN_SUPPORT]


METHODS = {
    "IGMM sequential": lambda X, spec, seed: igmm(X, spec, batch=False),
    "IGMM batch": lambda X, spec, seed: igmm(X, spec, batch=True),
    "GaussianMixture (BIC)": gmm_bic,
    "BayesianGaussianMixture": bgmm,
}


def score(found, truth):
    matched = match_scores(found, truth, radius=0.5)
    return {"count_error": abs(len(found) - len(truth)), "ospa": ospa(found, truth, cutoff=1.0),
            "precision": matched["precision"], "recall": matched["recall"], "clusters": len(found)}


def evaluate(spec, scenes, orders, spread_scenes, progress):
    per_method = {name: {"scores": [], "spread": [], "spread_std": [], "seconds": 0.0} for name in METHODS}
    for seed in range(scenes):
        truth, X = make_scene(spec, seed)
        for name, method in METHODS.items():
            start = time.perf_counter()
            per_method[name]["scores"].append(score(method(X, spec, seed), truth))
            per_method[name]["seconds"] += time.perf_counter() - start
        progress.update(1)
    rng = np.random.default_rng(0)
    for seed in range(spread_scenes):
        _, X = make_scene(spec, seed)
        permutations = [rng.permutation(len(X)) for _ in range(orders)]
        for name, method in METHODS.items():
            counts = [len(method(X[order], spec, seed)) for order in permutations]
            per_method[name]["spread"].append(max(counts) - min(counts))
            per_method[name]["spread_std"].append(float(np.std(counts)))
        progress.update(1)
    summary = {}
    for name, result in per_method.items():
        scores = result["scores"]
        summary[name] = {key: float(np.mean([s[key] for s in scores]))
                         for key in ("count_error", "ospa", "precision", "recall", "clusters")}
        summary[name].update(min_precision=float(min(s["precision"] for s in scores)),
                             min_recall=float(min(s["recall"] for s in scores)),
                             order_spread_max_minus_min=float(np.mean(result["spread"])),
                             order_spread_std=float(np.mean(result["spread_std"])),
                             seconds_per_scene=result["seconds"] / len(scores))
    return summary


def print_table(title, spec, summary):
    print(f"\n{title}: {spec['objects']} objects in {spec['size']:.0f} x {spec['size']:.0f} m, "
          f"Poisson({spec['rate']}) detections, noise {spec['noise']} m, clutter {spec['clutter']:.0%}")
    print(f"{'method':26s} {'count err':>9s} {'OSPA m':>7s} {'prec':>6s} {'recall':>6s} "
          f"{'min P/R':>9s} {'spread':>7s} {'s/scene':>8s}")
    for name, s in summary.items():
        print(f"{name:26s} {s['count_error']:9.2f} {s['ospa']:7.3f} {s['precision']:6.3f} {s['recall']:6.3f} "
              f"{s['min_precision']:4.2f}/{s['min_recall']:4.2f} {s['order_spread_max_minus_min']:7.2f} "
              f"{s['seconds_per_scene']:8.3f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 scenes, spread over 3 orders of 1 scene")
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--orders", type=int, default=20)
    parser.add_argument("--spread-scenes", type=int, default=3, help="scenes whose orders are shuffled")
    args = parser.parse_args()
    scenes, orders, spread = (2, 3, 1) if args.quick else (args.scenes, args.orders, args.spread_scenes)
    print(f"load average {os.getloadavg()[0]:.2f}; {scenes} scenes per scenario, spread over {orders} "
          f"random orders of the first {spread} scenes")
    results = {}
    warnings.filterwarnings("ignore", message=".*converge.*")  # sklearn's non-convergence warnings
    with tqdm(total=len(SCENARIOS) * (scenes + spread), desc="scenes", unit="scene") as progress:
        for title, spec in SCENARIOS.items():
            results[title] = {"scene": spec, "methods": evaluate(spec, scenes, orders, spread, progress)}
    for title, result in results.items():
        print_table(title, result["scene"], result["methods"])
    target = results[TARGET]["methods"]
    checks = {f"{name}: precision >= 0.95, recall >= 0.95, OSPA <= 0.2 m":
              s["precision"] >= 0.95 and s["recall"] >= 0.95 and s["ospa"] <= 0.2
              for name, s in target.items() if name.startswith("IGMM")}
    checks["IGMM batch: zero spread over orders"] = target["IGMM batch"]["order_spread_max_minus_min"] == 0
    print("\ntargets (" + TARGET + "):")
    for text, ok in checks.items():
        print(f"  {'met' if ok else 'NOT met'}: {text}")
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    (OUT_DIR / "igmm_quality.json").write_text(json.dumps(
        {"quick": args.quick, "scenes": scenes, "orders": orders, "spread_scenes": spread, "results": results,
         "targets": checks}, indent=2))
    plot(results, OUT_DIR / "igmm_quality.png")
    print(f"wrote {OUT_DIR / 'igmm_quality.json'} and igmm_quality.png")
    return 0


def plot(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spec = SCENARIOS[TARGET]
    truth, X = make_scene(spec, 0)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    ax = axes[0]
    ax.plot(X[:, 0], X[:, 1], ".", color="0.7", markersize=3, label="detections (10% clutter)")
    ax.plot(truth[:, 0], truth[:, 1], "k+", markersize=12, label="true objects")
    for (name, method), marker in zip(METHODS.items(), ("o", "s", "^", "v")):
        found = method(X, spec, 0)
        ax.plot(found[:, 0], found[:, 1], marker, fillstyle="none", markersize=9, label=name)
    ax.set_aspect("equal")
    ax.set_title(f"scene 0, {TARGET}")
    ax.legend(fontsize=7, loc="upper right")
    ax = axes[1]
    names = list(METHODS)
    width = 0.8 / len(results)
    for i, (title, result) in enumerate(results.items()):
        values = [result["methods"][n]["ospa"] for n in names]
        ax.bar(np.arange(len(names)) + i * width, values, width, label=title)
    ax.axhline(0.2, color="k", linestyle=":", label="target 0.2 m")
    ax.set_xticks(np.arange(len(names)) + width)
    ax.set_xticklabels([n.replace(" ", "\n", 1) for n in names], fontsize=8)
    ax.set_ylabel("mean OSPA (m), cut-off 1 m")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
