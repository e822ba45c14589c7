#!/usr/bin/env python3
"""lfd_controller benchmark: learning from person-like demonstrators (headline) and from the
synthetic expert (sanity), with CIOC (Levine and Koltun 2012).

1. People (issue 14; headline): for each person-like style (cautious, sporty, steady) and for 10
   demos mixed from all styles, on static, moving and oscillating obstacles: 10 demonstrations
   (lfd_controller.demonstrators; they do not optimise our features), a reward learned with
   learning.fit_person_reward (LinearCIOC over person_features(), sign prior PERSON_SIGNS, 4 s
   windows from the recorded states, Gauss-Newton Hessian, learned command noise), driven by the
   receding-horizon controller (learning.PERSON_CONTROLLER: up to 8 s look-ahead, ending about
   at arrival at the reward's preferred speed (at least 3.2 s), detour seeds, one alternative seed
   per cycle, discount 0.97 per step, absorbing goal region 0.25 m with a per-step time cost before
   arrival derived from the reward (planner.ArrivalReward); cycle budget 100 ms) on
   held-out starts (100; --quick 10; --heldout-seed 5: the validation starts) with
   planner.CollisionBarrier (a fixed, not learned, penalty inside robot + obstacle radius + 0.1 m)
   added to the learned reward; behaviour cloning tuned
   on validation starts (size, L2 regularisation, three initialisations; clean + DART
   noise-injected drives); the driver's own success on the same starts as the reference
   ceiling. Two obstacle/goal layouts no demo showed are driven with the reward and the clone
   learned on the static scenario.
   Targets: learned-controller success >= 90 % and >= 0.9 x the driver's, >= 20 points above
   behaviour cloning, collision rate <= the driver's.
2. Synthetic expert (sanity row): reward recovery (cosine, reward loss) for 4, 8, 16 demos and the
   controller's success on static and moving obstacles from 10 expert demos.
3. Cost: learning time for 16 person demos (target < 60 s), controller cycle time (>= 10 Hz).
Figures and JSON in artifacts/bench/ (lfd_bench*.json, lfd_*.png).
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

from lfd_controller.baseline import BC_GRID, BehaviourCloning, tune_behaviour_cloning  # noqa: E402
from lfd_controller.cioc import LinearCIOC  # noqa: E402
from lfd_controller.demonstrators import (  # noqa: E402
    STYLES,
    PersonLikeDriver,
    dart_demos,
    person_demos,
    unseen_layouts,
)
from lfd_controller.demos import trim_to_goal  # noqa: E402
from lfd_controller.expert import SyntheticExpert, true_reward  # noqa: E402
from lfd_controller.features import Task  # noqa: E402
from lfd_controller.gp_cioc import GPCIOC  # noqa: E402
from lfd_controller.learning import PERSON_CONTROLLER, fit_person_reward  # noqa: E402
from lfd_controller.planner import (  # noqa: E402
    CollisionBarrier,
    RecedingHorizonController,
    optimise_commands,
    plan_from_seeds,
    trajectory_reward,
)
from lfd_controller.plots import plot_demonstrations, plot_reward_field, plot_trajectories  # noqa: E402
from robot_sim.scenarios import load_scenario, run_episode  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "artifacts" / "bench"
TEST_SEED = 4         # held-out test starts of the person rows; 5 = validation starts (BC tuning)


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


def outcome_of(episodes):
    return {"success": float(np.mean([e.success for e in episodes])),
            "collided": float(np.mean([e.collided for e in episodes])),
            "timeout": float(np.mean([not e.reached and not e.collided for e in episodes])),
            "mean_time_s": float(np.mean([e.times[-1] for e in episodes if e.success] or [np.nan]))}


class DriverEpisode:
    """A person-like drive seen as an EpisodeResult (success, collided, reached, times)."""

    def __init__(self, result, scenario):
        self.success, self.collided = result["success"], result["collided"]
        self.reached = result["reached"]
        self.times = np.array([result["time"] if result["success"] else scenario.max_time])


def driver_reference(scenario, group, starts, seed):
    names = sorted(STYLES) if group == "mixed" else [group]
    drivers = [PersonLikeDriver(name, seed + i) for i, name in enumerate(names)]
    return [DriverEpisode(drivers[k % len(drivers)].success(scenario, start), scenario)
            for k, start in enumerate(starts)]


def controller_episodes(reward, scenario, starts, desc, cycle_times, barrier=True):
    task = Task.from_scenario(scenario)
    planned = CollisionBarrier(reward, scenario.clearance) if barrier else reward
    controller = RecedingHorizonController(planned, scenario.model(), budget=0.1, **PERSON_CONTROLLER)
    episodes = []
    for start in tqdm(starts, desc=desc, leave=False):
        controller.reset()
        episodes.append(run_episode(scenario, lambda x, t: controller.act(x, t, task), start))
        cycle_times.extend(controller.cycle_times_)
    return episodes


def clone_episodes(clone, scenario, starts):
    task = Task.from_scenario(scenario)
    return [run_episode(scenario, lambda x, t: clone.predict(x, t, task), start) for start in starts]


def learn_group(scenario, group, args):
    """(reward, tuned clone, info) from 10 demos of `group` in `scenario`."""
    starts = scenario.sample_starts(10, seed=3)
    demos = person_demos(scenario, group, starts, seed=1)
    started = time.monotonic()
    reward, learner = fit_person_reward(demos)
    learn_s = time.monotonic() - started
    train = person_demos(scenario, group, starts, seed=1) + dart_demos(scenario, group, starts, seed=2)
    validation = scenario.sample_starts(10, seed=5)
    grid = {"hidden": ((64, 64),), "alpha": (1e-4, 1e-2)} if args.quick else BC_GRID
    clone, table = tune_behaviour_cloning(
        train, lambda c: np.mean([e.success for e in clone_episodes(c, scenario, validation)]),
        grid=grid, seeds=(0,) if args.quick else (0, 1, 2))
    weights = dict(zip(reward.features.names, np.round(reward.weights, 4).tolist()))
    noise = None if learner.noise_std_ is None else np.round(learner.noise_std_, 4).tolist()
    return reward, clone, {"demos": len(demos), "learn_s": learn_s, "weights": weights,
                           "noise_std": noise,
                           "bc_choice": clone.get_params(), "bc_validation": table}


def people(args, results):
    runs = args.runs or (10 if args.quick else 100)
    groups = args.styles or (sorted(STYLES) + ["mixed"])
    rows, cycle_times = [], []
    layouts = unseen_layouts()
    for group in groups:
        learned = {}
        for name in ("static_obstacle", "moving_obstacle", "oscillating_obstacle"):
            scenario = load_scenario(name)
            learned[name] = learn_group(scenario, group, args)
            print(f"  {group} / {name}: learned from {learned[name][2]['demos']} demos in "
                  f"{learned[name][2]['learn_s']:.0f} s: {learned[name][2]['weights']}", flush=True)
        cases = [(load_scenario(n), n) for n in learned] + [(s, "static_obstacle") for s in layouts]
        for scenario, source in cases:
            reward, clone, info = learned[source]
            starts = scenario.sample_starts(runs, seed=args.heldout_seed)
            row = {"group": group, "scenario": scenario.name, "learned_on": source, "runs": runs,
                   "heldout_seed": args.heldout_seed,
                   "learn": {k: v for k, v in info.items() if k != "bc_validation"}}
            cioc = controller_episodes(reward, scenario, starts, f"cioc {group}/{scenario.name}",
                                       cycle_times)
            row["driver"] = outcome_of(driver_reference(scenario, group, starts, 900))
            row["cioc"] = outcome_of(cioc)
            row["behaviour_cloning"] = outcome_of(clone_episodes(clone, scenario, starts))
            plot_trajectories(cioc, scenario,
                              OUT / f"lfd_people_{group}_{scenario.name}_cioc{suffix(args)}.png",
                              title=f"CIOC, {group} demos ({scenario.name})")
            d, c, b = row["driver"], row["cioc"], row["behaviour_cloning"]
            row["targets"] = {"success_90": c["success"] >= 0.9,
                              "vs_driver_0.9x": c["success"] >= 0.9 * d["success"],
                              "bc_plus_20": c["success"] >= b["success"] + 0.2,
                              "collisions_le_driver": c["collided"] <= d["collided"]}
            rows.append(row)
            print(f"  {group:8s} {scenario.name:22s} driver {d['success']:4.0%} "
                  f"(coll {d['collided']:4.0%}) | "
                  f"CIOC {c['success']:4.0%} (coll {c['collided']:4.0%}, timeout {c['timeout']:4.0%}) | "
                  f"BC {b['success']:4.0%} (coll {b['collided']:4.0%}) | targets met: "
                  f"{sum(row['targets'].values())}/4", flush=True)
    results["people"] = rows
    if cycle_times:
        cycle = np.array(cycle_times) * 1000.0
        results.setdefault("cost", {}).update(people_cycle_ms_mean=float(cycle.mean()),
                                              people_cycle_ms_p95=float(np.percentile(cycle, 95)),
                                              people_cycle_ms_p99=float(np.percentile(cycle, 99)),
                                              people_cycle_ms_max=float(cycle.max()),
                                              people_cycle_over_100ms=float(np.mean(cycle > 100.0)),
                                              people_cycles=int(len(cycle)))
        print(f"  controller cycle (person rewards, {len(cycle)} cycles): mean {cycle.mean():.1f} ms, "
              f"p95 {np.percentile(cycle, 95):.1f} ms, p99 {np.percentile(cycle, 99):.1f} ms, max "
              f"{cycle.max():.1f} ms, {np.mean(cycle > 100.0):.1%} over the 100 ms budget", flush=True)
    plot_people(rows, suffix(args))
    if not args.quick or args.learn_time:
        scenario = load_scenario("static_obstacle")
        starts = scenario.sample_starts(16, seed=6)
        demos = [trim_to_goal(d, 0) for d in person_demos(scenario, "mixed", starts, seed=7)]
        started = time.monotonic()
        fit_person_reward(demos)
        seconds = time.monotonic() - started
        results.setdefault("cost", {})["learn_16_person_demos_s"] = seconds
        print(f"  learning time, 16 mixed person demos ({sum(d.length for d in demos)} steps): "
              f"{seconds:.1f} s (target < 60 s)", flush=True)


def suffix(args) -> str:
    """"_seed<N>" for held-out starts other than the test starts (seed 4), so a validation run
    does not overwrite the test run's figures and JSON."""
    return "" if args.heldout_seed == TEST_SEED else f"_seed{args.heldout_seed}"


def plot_people(rows, tag=""):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not rows:
        return
    fig, ax = plt.subplots(figsize=(max(8, 0.6 * len(rows)), 4.5))
    x = np.arange(len(rows))
    for i, (key, label) in enumerate((("driver", "driver (ceiling)"), ("cioc", "CIOC controller"),
                                      ("behaviour_cloning", "tuned behaviour cloning"))):
        ax.bar(x - 0.27 + 0.27 * i, [r[key]["success"] for r in rows], 0.27, label=label)
    ax.axhline(0.9, color="k", lw=0.8, ls="--")
    ax.set_xticks(x)
    ax.set_xticklabels([f"{r['group']}\n{r['scenario']}" for r in rows], rotation=60, ha="right",
                       fontsize=7)
    ax.set_ylabel("success (goal, no collision)")
    ax.set_title("learning from person-like demonstrators (held-out starts)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / f"lfd_people{tag}.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run: fewer demos and starts")
    parser.add_argument("--only", choices=["people", "recovery", "behaviour"], help="run one part")
    parser.add_argument("--runs", type=int, help="held-out starts per person row (default 100; "
                                                 "--quick 10)")
    parser.add_argument("--learn-time", action="store_true",
                        help="with --quick: also time learning 16 mixed person demos")
    parser.add_argument("--styles", nargs="*", choices=sorted(STYLES) + ["mixed"],
                        help="person-like groups to run (default: all styles and mixed)")
    parser.add_argument("--heldout-seed", type=int, default=TEST_SEED,
                        help=f"seed of the starts the person rows are driven from (default "
                             f"{TEST_SEED}: the held-out test starts; 5: the validation starts, for "
                             f"choosing settings; other seeds write *_seed<N> outputs)")
    args = parser.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    results = {"quick": args.quick, "heldout_seed": args.heldout_seed,
               "load_average_start": os.getloadavg()[0]}
    started = time.monotonic()
    if args.only in (None, "people"):
        print("person-like demonstrators (held-out starts; driver = the demonstrators' own success):",
              flush=True)
        people(args, results)
    if args.only in (None, "recovery"):
        print("sanity: reward recovery (static obstacle, synthetic expert):", flush=True)
        recovery(args, results)
    if args.only in (None, "behaviour"):
        print("sanity: behaviour from synthetic-expert demos (held-out starts):", flush=True)
        behaviour(args, results)
    results["seconds"] = time.monotonic() - started
    results["load_average_end"] = os.getloadavg()[0]
    name = ("lfd_bench" + (f"_{args.only}" if args.only else "") + ("_quick" if args.quick else "")
            + suffix(args) + ".json")
    (OUT / name).write_text(json.dumps(results, indent=2))
    print(f"results in {OUT / name} ({results['seconds']:.0f} s; load average "
          f"{results['load_average_start']:.1f} -> {results['load_average_end']:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
