#!/usr/bin/env python3
"""lfd_controller sanity benchmark: learning from the synthetic expert (optimal under a known reward
over the learner's own features and model - the one case the learner cannot get wrong).

1. Reward recovery: cosine(learned, true weights) and reward loss on training and held-out starts
   for 4, 8, 16 expert demos (linear CIOC; the GP variant on 8).
2. Behaviour: the controller's success on static and moving obstacles from 10 expert demos, against
   untuned behaviour cloning (a sanity row only; the headline is bench/lfd_controller/lfd_bench.py).
3. Learning time of 16 x 50-step demos (linear and GP).
Figures and JSON in artifacts/bench/ (lfd_sanity*.json, lfd_*.png).
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from lfd_controller.baseline import BehaviourCloning  # noqa: E402
from lfd_controller.cioc import LinearCIOC  # noqa: E402
from lfd_controller.expert import SyntheticExpert, true_reward  # noqa: E402
from lfd_controller.features import Task  # noqa: E402
from lfd_controller.gp_cioc import GPCIOC  # noqa: E402
from lfd_controller.planner import (  # noqa: E402
    RecedingHorizonController,
    optimise_commands,
    plan_from_seeds,
    trajectory_reward,
)
from lfd_controller.plots import plot_demonstrations, plot_reward_field, plot_trajectories  # noqa: E402
from robot_sim.scenarios import load_scenario, run_episode  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "artifacts" / "bench"


def cosine(a, b):
    return float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


def true_value(scenario, start, actions):
    model, task = scenario.model(), Task.from_scenario(scenario)
    return trajectory_reward(true_reward(), model, task, start, 0.0, actions, gradient=False)[0]


def reward_loss(scenario, reward, starts, expert_plans, steps):
    """Mean over starts of R_true(plan under true reward) - R_true(plan under learned reward).

    The reference is the better of the expert's plan and the true-reward optimum reached from the
    learned plan (both local optimisers; without this the loss can go negative when the learned
    reward's plan lands in a better basin than the expert's)."""
    model, task = scenario.model(), Task.from_scenario(scenario)
    losses = []
    for start, best in zip(starts, expert_plans):
        plan = plan_from_seeds(reward, model, task, start, 0.0, steps, max_iter=200)[0]
        refined = optimise_commands(true_reward(), model, task, start, 0.0, plan, max_iter=200)[0]
        reference = max(true_value(scenario, start, best), true_value(scenario, start, refined))
        losses.append(reference - true_value(scenario, start, plan))
    return float(np.mean(losses)), float(np.max(losses))


def recovery(args, results):
    scenario, steps = load_scenario("static_obstacle"), 50
    expert = SyntheticExpert(steps=steps)
    counts = [4, 8] if args.quick else [4, 8, 16]
    train = scenario.sample_starts(max(counts), seed=1)
    held = scenario.sample_starts(4 if args.quick else 10, seed=2)
    demos = [expert.demonstrate(scenario, s) for s in tqdm(train, desc="expert demos (train)")]
    held_plans = [expert.plan(scenario, s) for s in tqdm(held, desc="expert plans (held-out)")]
    truth = true_reward().weights
    rows = []
    for n in counts:
        learner = LinearCIOC(random_state=0).fit(demos[:n])
        row = {"demos": n, "kind": "linear", "cosine": cosine(learner.weights_, truth),
               "weights": (learner.weights_ / np.linalg.norm(learner.weights_)).tolist(),
               "fit_seconds": learner.fit_time_, "beta": learner.beta_}
        row["loss_train"], row["loss_train_max"] = reward_loss(
            scenario, learner.reward_, train[:n], [d.actions for d in demos[:n]], steps)
        row["loss_held_out"], row["loss_held_out_max"] = reward_loss(
            scenario, learner.reward_, held, held_plans, steps)
        rows.append(row)
        print(f"  linear, {n:2d} demos: cos(learned, true) = {row['cosine']:.4f}, reward loss "
              f"train {row['loss_train']:.3f}, held-out {row['loss_held_out']:.3f} "
              f"(fit {row['fit_seconds']:.1f} s, beta {row['beta']:.1e})", flush=True)
    gp = GPCIOC(random_state=0).fit(demos[:8])
    gp_row = {"demos": 8, "kind": "gp", "fit_seconds": gp.fit_time_, "beta": gp.beta_}
    gp_row["loss_held_out"], gp_row["loss_held_out_max"] = reward_loss(scenario, gp.reward_, held,
                                                                       held_plans, steps)
    rows.append(gp_row)
    print(f"  GP,      8 demos: reward loss held-out {gp_row['loss_held_out']:.3f} (fit "
          f"{gp.fit_time_:.1f} s, beta {gp.beta_:.1e})", flush=True)
    results["recovery"] = {"true_weights": (truth / np.linalg.norm(truth)).tolist(), "rows": rows,
                           "true_reward_scale_note": "reward loss in units of the true reward summed "
                                                     "over 50 steps"}
    plot_demonstrations(demos, OUT / "lfd_recovery_demos.png")
    plot_reward_field(LinearCIOC(random_state=0).fit(demos[:8]).reward_, scenario,
                      OUT / "lfd_reward_field.png", demos[:8])
    plot_recovery(rows, truth)
    if not args.quick:
        timing = LinearCIOC(random_state=0).fit(demos[:16])
        results["cost"] = {"learn_16x50_linear_s": timing.fit_time_}
        gp16 = GPCIOC(random_state=0).fit(demos[:16])
        results["cost"]["learn_16x50_gp_s"] = gp16.fit_time_
        print(f"  learning time, 16 demos x 50 steps: linear {timing.fit_time_:.1f} s, GP "
              f"{gp16.fit_time_:.1f} s (target < 60 s)", flush=True)


def plot_recovery(rows, truth):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    linear = [r for r in rows if r["kind"] == "linear"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    names = true_reward().features.names
    x = np.arange(len(names))
    left.bar(x - 0.3, truth / np.linalg.norm(truth), 0.15, label="true", color="k")
    for i, row in enumerate(linear):
        left.bar(x - 0.15 + 0.15 * i, row["weights"], 0.15, label=f"{row['demos']} demos")
    left.set_xticks(x)
    left.set_xticklabels(names, rotation=30, ha="right")
    left.set_title("normalised weights: learned vs true")
    left.legend()
    right.plot([r["demos"] for r in linear], [r["loss_train"] for r in linear], "o-", label="training starts")
    right.plot([r["demos"] for r in linear], [r["loss_held_out"] for r in linear], "s-",
               label="held-out starts")
    right.set_xlabel("demonstrations")
    right.set_ylabel("reward loss (true reward)")
    right.set_title("reward loss (lower is better)")
    right.legend()
    fig.tight_layout()
    fig.savefig(OUT / "lfd_recovery.png", dpi=110)
    plt.close(fig)


def behaviour(args, results):
    runs = 20 if args.quick else 100
    results["behaviour"] = {}
    cycle_times = []
    for name in ("static_obstacle", "moving_obstacle"):
        scenario = load_scenario(name)
        task = Task.from_scenario(scenario)
        expert = SyntheticExpert(steps=70)
        demos = [expert.demonstrate(scenario, s)
                 for s in tqdm(scenario.sample_starts(10, seed=3), desc=f"expert demos ({name})")]
        reward = LinearCIOC(random_state=0).fit(demos).reward_
        clone = BehaviourCloning(random_state=0).fit(demos)   # untuned: a sanity row only
        controller = RecedingHorizonController(reward, scenario.model())
        starts = scenario.sample_starts(runs, seed=4)
        outcome = {}
        policies = {"cioc": lambda x, t, c=controller, k=task: c.act(x, t, k),
                    "behaviour_cloning": lambda x, t, c=clone, k=task: c.predict(x, t, k)}
        for label, policy in policies.items():
            episodes = []
            for start in tqdm(starts, desc=f"{label} ({name})"):
                controller.reset()
                episodes.append(run_episode(scenario, policy, start))
                cycle_times.extend(controller.cycle_times_ if label == "cioc" else [])
            outcome[label] = {"success": float(np.mean([e.success for e in episodes])),
                              "collided": float(np.mean([e.collided for e in episodes])),
                              "timeout": float(np.mean([not e.reached and not e.collided for e in episodes])),
                              "mean_time_s": float(np.mean([e.times[-1] for e in episodes if e.success]
                                                           or [np.nan]))}
            plot_trajectories(episodes, scenario, OUT / f"lfd_{name}_{label}.png",
                              title=f"{label} ({name})")
        target = 0.95 if name == "static_obstacle" else 0.90
        outcome.update(demos=len(demos), runs=runs, target=target)
        results["behaviour"][name] = outcome
        print(f"  {name}: CIOC success {outcome['cioc']['success']:.0%} (target {target:.0%}), "
              f"behaviour cloning {outcome['behaviour_cloning']['success']:.0%}; "
              f"ratio {outcome['cioc']['success'] / max(outcome['behaviour_cloning']['success'], 1e-9):.2f}",
              flush=True)
    cycle = np.array(cycle_times) * 1000.0
    results.setdefault("cost", {}).update(controller_cycle_ms_mean=float(cycle.mean()),
                                          controller_cycle_ms_p95=float(np.percentile(cycle, 95)),
                                          controller_cycle_ms_max=float(cycle.max()))
    print(f"  controller cycle: mean {cycle.mean():.1f} ms, p95 {np.percentile(cycle, 95):.1f} ms, "
          f"max {cycle.max():.1f} ms (budget 100 ms at 10 Hz)", flush=True)



def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run: fewer demos and starts")
    parser.add_argument("--only", choices=["recovery", "behaviour"], help="run one part")
    args = parser.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    results = {"quick": args.quick}
    started = time.monotonic()
    if args.only in (None, "recovery"):
        print("sanity: reward recovery (static obstacle, synthetic expert):", flush=True)
        recovery(args, results)
    if args.only in (None, "behaviour"):
        print("sanity: behaviour from synthetic-expert demos (held-out starts):", flush=True)
        behaviour(args, results)
    results["seconds"] = time.monotonic() - started
    name = "lfd_sanity" + (f"_{args.only}" if args.only else "") + ("_quick" if args.quick else "") + ".json"
    (OUT / name).write_text(json.dumps(results, indent=2))
    print(f"results in {OUT / name} ({results['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
