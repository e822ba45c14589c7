#!/usr/bin/env python3
"""lfd_controller benchmark: learning from people it was never tuned on (leave-one-family-out).

Demonstrators: the six structurally different families of lfd_controller.sim (tangent swerve,
potential field, pure pursuit + velocity obstacle, social force, sampling MPC, yielding velocity
obstacle from a delayed estimate), each as simulated people with their own speed, reaction
delay, stick, hand noise, side, clearance and overshoot.
For every family F left out, rotated over all families:

  * every choice - the learner's settings (CANDIDATES: with or without the controller-in-the-loop
    calibration) and behaviour cloning's size and L2 - is made on the OTHER families' validation
    rows only (a different person per family and scenario, validation starts, seed 5);
  * F's test person gives 10 demonstrations per scenario (static, moving, oscillating obstacle;
    only successful takes, up to 2 tries each); the reward is learned with the chosen settings
    (what `learn_reward --kind person` does) and driven (learning.person_controller with the
    saved settings) from held-out starts (seed 4; --test-seed draws others) with the node's
    0.1 s cycle budget - what a user gets - and, beside it, without a budget; the two unseen
    layouts are driven with the static reward;
  * a reward the acceptance check refuses is not served: its row scores 0 % (refusals are a
    column), and it is driven anyway to show whether the refusal was right;
  * per row: success, collisions, median time to goal next to the person's own on the same
    starts, tuned behaviour cloning (same demos + DART drives) and, where the person reaches the
    goal in at least half the drives, the targets (success >= 90 %, 0 collisions, time <= 1.3 x
    the person's median, >= cloning + 10 points where cloning < 90 %); below the table, for
    each judged row, the controller's time over the person's from the same starts (not a target).

Resumable: each row is written to artifacts/bench/lfd/{validation,rows}/ as soon as it is done
and skipped when it exists; --families splits the work between processes; --phase table prints
the table from the files. Run it under `nice -n 10`.
"""
import argparse
import json
import os
import pickle
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from lfd_controller.baseline import tune_behaviour_cloning  # noqa: E402
from lfd_controller.features import Task  # noqa: E402
from lfd_controller.learning import fit_person_reward, load_reward, person_controller, save_reward  # noqa: E402
from lfd_controller.params import RewardControllerParams  # noqa: E402
from lfd_controller.plots import plot_trajectories  # noqa: E402
from lfd_controller.sim import FAMILIES, dart_demos, make_person, person_demos, unseen_layouts  # noqa: E402
from robot_sim.scenarios import load_scenario, run_episode  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "artifacts" / "bench" / "lfd"
SCENARIOS = ("static_obstacle", "moving_obstacle", "oscillating_obstacle")
LAYOUTS = ("layout_offset_goal", "layout_crossing")
# The learner's settings to choose from: CIOC + the acceptance check with calibration (speed and
# obstacle scales, barrier margin), or CIOC + the acceptance check alone (the reward and the 0.1 m
# barrier as learned; the report only). Validation rows written with the name "cioc_only" (CIOC
# without the check: the same reward and drives) count as "checked".
CANDIDATES = {"calibrated": {}, "checked": {"rounds": 1, "margin_bounds": (0.1, 0.1)}}
BC_GRID = {"hidden": ((32,), (64, 64)), "alpha": (1e-4, 1e-2)}
DEMOS, VALIDATION_STARTS = 10, 4
BUDGETS = (0.1, None)   # the node's cycle budget (what users get), and none (load-independent)
DEMO_POOL = 30      # starts the person drives from until DEMOS good takes (2 tries each)
TEST_SEED, VALIDATION_SEED, DEMO_SEED = 4, 5, 3
# How the controller knows the obstacle's future: "scenario" - the simulator's own time-indexed
# obstacle, as reward_controller takes it in the simulator; "tracked" - its position and velocity
# now, predicted at constant velocity, as the node does from the obstacle topic on a robot.
PREDICTION = "scenario"
OBSTACLE_ACCEL = RewardControllerParams.obstacle_accel     # the node's floor


def scenario_named(name):
    layouts = {s.name: s for s in unseen_layouts()}
    return layouts[name] if name in layouts else load_scenario(name)


def person_seed(family, scenario, role):
    """A different person for every family, scenario and role (validation / test)."""
    base = {"validation": 2000, "test": 1000}[role]
    return base + 10 * sorted(FAMILIES).index(family) + SCENARIOS.index(scenario)


def summary(episodes, scenario):
    """Success and collision rates, median time of the successful drives, and the closest
    approach to the obstacle (m beyond touching) over all drives (its minimum and median)."""
    times = [e["time"] for e in episodes if e["success"]]
    closest = [e["closest"] for e in episodes if e.get("closest") is not None]
    return {"runs": len(episodes), "success": float(np.mean([e["success"] for e in episodes])),
            "collided": float(np.mean([e["collided"] for e in episodes])),
            "median_time": float(np.median(times)) if times else float("nan"),
            "closest_min": float(min(closest)) if closest else float("nan"),
            "closest_median": float(np.median(closest)) if closest else float("nan")}


def episode_record(result):
    return {"success": bool(result.success), "collided": bool(result.collided),
            "time": float(result.times[-1]), "closest": float(result.min_clearance)}


def drive_controller(reward, scenario, starts, desc, settings, cycles=None, budget=None):
    """The person controller's drives with a cycle budget of `budget` s (None: none, so the drives
    do not depend on how busy the machine is); each cycle's CPU seconds are collected in `cycles`
    (the figure for the 10 Hz target: a cycle that needs < 100 ms of CPU keeps 10 Hz on a free
    core)."""
    controller = person_controller(reward, scenario, budget=budget, settings=settings)
    task = Task.from_scenario(scenario)
    episodes, results, used = [], [], []

    def policy(state, t):
        started = time.process_time()
        seen = task if PREDICTION == "scenario" else Task.tracked(scenario, t, accel=OBSTACLE_ACCEL)
        command = controller.act(state, t, seen)
        used.append(time.process_time() - started)
        return command
    for start in tqdm(starts, desc=desc, leave=False, mininterval=5):
        controller.reset()
        result = run_episode(scenario, policy, start)
        results.append(result)
        episodes.append(episode_record(result))
    if cycles is not None:
        cycles.extend(used)
    return episodes, results


def drive_clone(clone, scenario, starts):
    task = Task.from_scenario(scenario)
    return [episode_record(run_episode(scenario, lambda x, t: clone.predict(x, t, task), s)) for s in starts]


def drive_person(family, seed, scenario, starts):
    person = make_person(family, seed).person
    driver = make_person(family, seed + 500, person=person)
    return [{k: r[k] for k in ("success", "collided", "time", "closest")}
            for r in (driver.success(scenario, s) for s in starts)]


def learn(demos, settings):
    """(reward, info): the person pipeline's reward; wall and CPU seconds (this process's CPU
    time: what learning costs on a free core) and the acceptance report."""
    started, cpu = time.monotonic(), time.process_time()
    reward, learner = fit_person_reward(demos, calibration=settings)
    acceptance = None if learner.acceptance_ is None else learner.acceptance_.to_dict()
    return reward, {"learn_s": time.monotonic() - started, "learn_cpu_s": time.process_time() - cpu,
                    "acceptance": acceptance, "driving": learner.driving_}


def person_takes(scenario, family, seed):
    """The person's DEMOS good takes (drives from a pool of starts, two tries each)."""
    return person_demos(scenario, family, scenario.sample_starts(DEMO_POOL, seed=DEMO_SEED), seed=seed,
                        max_tries=2, wanted=DEMOS)


def bc_training(scenario, family, seed):
    """Cloning's data: the same takes and DART drives of the same person from their starts."""
    demos = person_takes(scenario, family, seed)
    person = make_person(family, seed).person
    return demos + dart_demos(scenario, family, [d.start for d in demos], seed=seed + 1, person=person)


def write(path, data):
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    tmp.replace(path)


def validation_row(family, name):
    """Every candidate's and every cloning setting's success on one family's validation person."""
    path = OUT / "validation" / f"{family}__{name}.json"
    if path.exists():
        row = json.loads(path.read_text())
        if "cioc_only" in row["learner"]:
            row["learner"]["checked"] = row["learner"].pop("cioc_only")
        return row
    scenario, seed = load_scenario(name), person_seed(family, name, "validation")
    demos = person_takes(scenario, family, seed)
    starts = scenario.sample_starts(VALIDATION_STARTS, seed=VALIDATION_SEED)
    row = {"family": family, "scenario": name, "demos": len(demos), "learner": {}, "clone": {}}
    for label, settings in CANDIDATES.items():
        if not demos:
            row["learner"][label] = {"success": 0.0}
            continue
        reward, info = learn(demos, settings)
        episodes, _ = drive_controller(reward, scenario, starts, f"validate {family}/{name}/{label}",
                                       info["driving"])
        row["learner"][label] = dict(summary(episodes, scenario), **info)
    if demos:
        _, table = tune_behaviour_cloning(
            bc_training(scenario, family, seed),
            lambda clone: np.mean([e["success"] for e in drive_clone(clone, scenario, starts)]),
            grid=BC_GRID, seeds=(0,))
        row["clone"] = {f"{t['hidden']}|{t['alpha']}": t["score"] for t in table}
    write(path, row)
    print(f"  validation {family}/{name}: {len(demos)} demos; learner "
          + ", ".join(f"{k} {v['success']:.0%}" for k, v in row["learner"].items()), flush=True)
    return row


def validation_score(row, label):
    """A candidate's score on one validation row: its success, scaled down by 1.3 / (time ratio)
    where it takes longer than 1.3 x the person's median time on the same starts (the targets)."""
    result = row["learner"][label]
    if not row["demos"] or not result["success"]:
        return float(result.get("success", 0.0))
    scenario = load_scenario(row["scenario"])
    starts = scenario.sample_starts(VALIDATION_STARTS, seed=VALIDATION_SEED)
    person = summary(drive_person(row["family"], person_seed(row["family"], row["scenario"], "validation"),
                                  scenario, starts), scenario)["median_time"]
    ratio = result["median_time"] / person if person == person else 1.0
    return result["success"] * min(1.0, 1.3 / ratio)


def choose(left_out, validation):
    """The learner candidate and the cloning setting with the best mean validation score on the
    families other than `left_out` (learner: validation_score; cloning: success; ties: the first
    candidate / grid point)."""
    others = [row for row in validation if row["family"] != left_out]
    learner = max(CANDIDATES, key=lambda c: (np.mean([validation_score(r, c) for r in others]),
                                             -list(CANDIDATES).index(c)))
    keys = sorted({k for r in others for k in r["clone"]})
    clone = max(keys, key=lambda k: np.mean([r["clone"].get(k, 0.0) for r in others]))
    return learner, clone


def clone_from(key, demos):
    from lfd_controller.baseline import BehaviourCloning

    hidden, alpha = key.split("|")
    return BehaviourCloning(tuple(json.loads(hidden)), 2000, 0, float(alpha)).fit(demos)


def learned_for(family, name, choice):
    """(reward, clone, info) of the family's test person on a standard scenario (cached on disk)."""
    folder = OUT / "learned"
    reward_path, clone_path = folder / f"{family}__{name}.yaml", folder / f"{family}__{name}.clone.pkl"
    info_path = folder / f"{family}__{name}.json"
    if reward_path.exists() and clone_path.exists() and info_path.exists():
        return (load_reward(reward_path), pickle.loads(clone_path.read_bytes()),
                json.loads(info_path.read_text()))
    scenario, seed = load_scenario(name), person_seed(family, name, "test")
    demos = person_takes(scenario, family, seed)
    if not demos:        # nothing to learn from: the row reports the person alone
        return None, None, {"demos": 0, "learn_s": float("nan"), "acceptance": None,
                            "person": make_person(family, seed).describe()}
    reward, info = learn(demos, CANDIDATES[choice[0]])
    clone = clone_from(choice[1], bc_training(scenario, family, seed))
    weights = dict(zip(reward.features.names, np.round(reward.weights, 4).tolist()))
    info.update(demos=len(demos), person=make_person(family, seed).describe(), learner=choice[0],
                clone=choice[1], weights=weights)
    save_reward(reward, reward_path)
    clone_path.write_bytes(pickle.dumps(clone))
    write(info_path, info)
    return reward, clone, info


def test_row(family, name, choice, runs):
    path = OUT / "rows" / f"{family}__{name}.json"
    if path.exists():
        return json.loads(path.read_text())
    source = "static_obstacle" if name in LAYOUTS else name
    reward, clone, info = learned_for(family, source, choice)
    scenario = scenario_named(name)
    starts = scenario.sample_starts(runs, seed=TEST_SEED)
    failed = [{"success": False, "collided": False, "time": scenario.max_time}] * runs
    acceptance = info.get("acceptance") or {}
    refused = reward is not None and not acceptance.get("accepted", True)
    person = drive_person(family, person_seed(family, source, "test"), scenario, starts)
    row = {"family": family, "scenario": name, "learned_on": source, "runs": runs,
           "demos": info["demos"], "learn": info, "refused": refused, "test_seed": TEST_SEED,
           "prediction": PREDICTION,
           "person": summary(person, scenario),
           "clone": summary(drive_clone(clone, scenario, starts) if reward is not None else failed,
                            scenario),
           "load_average": os.getloadavg()[0]}
    for budget in BUDGETS:           # the node's budget first: what a user gets
        key = "budget" if budget else "unbudgeted"
        cycles, episodes, results = [], failed, []          # no demonstrations: nothing drives
        if reward is not None:
            episodes, results = drive_controller(reward, scenario, starts, f"test {family}/{name} {key}",
                                                 info["driving"], cycles, budget)
        row[key] = dict(summary(episodes, scenario), budget=budget,
                        cycle_ms={"count": len(cycles), "mean": 1000 * float(np.mean(cycles or [0.0])),
                                  "p95": 1000 * float(np.percentile(cycles or [0.0], 95)),
                                  "over_100": int(np.sum(np.array(cycles) > 0.1))})
        if budget:
            row["paired"] = paired_times(episodes, person)
        if results and budget:
            plot_trajectories(results, scenario, OUT / "plots" / f"{family}__{name}.png",
                              title=f"learned from {family} ({name}, 0.1 s budget)"
                              + (" - REFUSED, driven anyway" if refused else ""))
    # what the user gets: a refused reward is not served, so its row scores 0 %
    row["controller"] = dict(row["budget"], **({"success": 0.0, "collided": 0.0,
                                                 "median_time": float("nan")} if refused else {}))
    row["targets"] = targets(row)
    write(path, row)
    print("  " + row_line(row), flush=True)
    return row


def paired_times(controller, person):
    """The controller's time over the person's from the same start, on the starts both reached
    the goal from: their count, the median of the per-start ratios and the ratio of the totals
    (a median of times compares different starts when the person's times fall in two groups,
    e.g. slipping past an oscillating obstacle or waiting for it)."""
    both = [(c["time"], p["time"]) for c, p in zip(controller, person) if c["success"] and p["success"]]
    if not both:
        return {"starts": 0, "median_ratio": float("nan"), "total_ratio": float("nan")}
    mine, theirs = np.array(both).T
    return {"starts": len(both), "median_ratio": float(np.median(mine / theirs)),
            "total_ratio": float(mine.sum() / theirs.sum())}


def add_room(path):
    """Rows written before the closest approach was recorded: drive the row's served reward again
    with the budget from the same starts (and the person) for the closest approach only."""
    row = json.loads(path.read_text())
    if "closest_min" in row["budget"] or not row["demos"]:
        return row
    scenario = scenario_named(row["scenario"])
    folder, source = OUT / "learned", row["learned_on"]
    reward = load_reward(folder / f"{row['family']}__{source}.yaml")
    starts = scenario.sample_starts(row["runs"], seed=row.get("test_seed", 4))  # older rows: 4
    episodes, _ = drive_controller(reward, scenario, starts, f"room {row['family']}/{row['scenario']}",
                                   row["learn"]["driving"], None, 0.1)
    person = drive_person(row["family"], person_seed(row["family"], source, "test"), scenario, starts)
    row["room"] = {"budget": summary(episodes, scenario), "person": summary(person, scenario),
                   "note": "re-driven for the closest approach (same reward, starts and budget)"}
    write(path, row)
    return row


TARGETS = ("success_90", "no_collisions", "time_1.3x", "clone_plus_10")


def targets(row):
    """The four targets (None where the person reaches the goal in fewer than half the drives)."""
    c, p, b = row["controller"], row["person"], row["clone"]
    ratio = c["median_time"] / p["median_time"] if p["median_time"] == p["median_time"] else float("nan")
    if p["success"] < 0.5:
        return {k: None for k in TARGETS}
    return {"success_90": c["success"] >= 0.9, "no_collisions": c["collided"] == 0.0,
            "time_1.3x": bool(ratio <= 1.3), "time_ratio": ratio,
            "clone_plus_10": b["success"] >= 0.9 or c["success"] >= b["success"] + 0.1}


def would_fail(row):
    """A refused reward driven anyway (with the budget) misses a target: the refusal was right."""
    d, p = row["budget"], row["person"]
    ratio = d["median_time"] / p["median_time"] if p["median_time"] == p["median_time"] else float("nan")
    return d["success"] < 0.9 or d["collided"] > 0 or not ratio <= 1.3


def row_line(row):
    c, p, b, t, u = row["controller"], row["person"], row["clone"], row["targets"], row["unbudgeted"]
    ratio = c["median_time"] / p["median_time"] if p["median_time"] == p["median_time"] else float("nan")
    met = ("n/a" if t["success_90"] is None
           else f"{sum(bool(t[k]) for k in TARGETS)}/4")
    refused = "-"
    if row["refused"]:
        d = row["budget"]
        refused = (f"refused (driven anyway {d['success']:.0%}, {d['collided']:.0%} coll.: "
                   + ("would fail" if would_fail(row) else "WRONGLY refused") + ")")
    time_cell = "-" if c["median_time"] != c["median_time"] else f"{c['median_time']:.1f} s ({ratio:.2f}x)"
    return (f"| {row['family']} | {row['scenario']} | {row['runs']} | {row['demos']} | "
            f"{p['success']:.0%} ({p['median_time']:.1f} s) | {refused} | {c['success']:.0%} | "
            f"{c['collided']:.0%} | {time_cell} | {u['success']:.0%} ({u['collided']:.0%}) | "
            f"{b['success']:.0%} | {met} |")


def table(rows):
    print("| family left out | scenario | starts | demos | the person (median time) | acceptance check | "
          "learned controller, 0.1 s budget | collisions | time to goal (x person) | "
          "no budget (collisions) | tuned cloning | targets met |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in rows:
        print(row_line(row))
    runs = sum(r["runs"] for r in rows)
    wins = sum(round(r["controller"]["success"] * r["runs"]) for r in rows)
    hits = sum(round(r["controller"]["collided"] * r["runs"]) for r in rows)
    free = sum(round(r["unbudgeted"]["success"] * r["runs"]) for r in rows if not r["refused"])
    print(f"learned controller (0.1 s budget, refused rows 0): {wins}/{runs} "
          f"({wins / max(runs, 1):.1%}), {hits} collisions; without the budget (served rows): {free}")
    for who in ("person", "clone"):
        got = sum(round(r[who]["success"] * r["runs"]) for r in rows)
        print(f"{who}: {got}/{runs}, {sum(round(r[who]['collided'] * r['runs']) for r in rows)} collisions")
    judged = [r for r in rows if r["targets"]["success_90"] is not None]
    met = sum(all(bool(r["targets"][k]) for k in TARGETS) for r in judged)
    learned = [r for r in rows if r["scenario"] in SCENARIOS and r["learn"].get("acceptance")]
    refused = [r for r in rows if r["refused"]]
    print(f"rows where the person reaches the goal in >= half the drives: {len(judged)}; meeting all "
          f"four targets: {met}/{len(judged)}")
    print(f"refused rows: {len(refused)} of {len(rows)} ({len(learned)} rewards learned); refusals "
          f"that would have failed if driven: {sum(would_fail(r) for r in refused)}/{len(refused)}")
    for r in rows:      # the room kept around a moving obstacle: the controller's vs the person's
        if r["scenario"] == "static_obstacle" or r["scenario"] == "layout_offset_goal" or not r["demos"]:
            continue
        room = r["budget"] if "closest_min" in r["budget"] else r.get("room", {}).get("budget")
        person = r["person"] if "closest_min" in r["person"] else r.get("room", {}).get("person")
        shown = (r["learn"].get("acceptance") or {}).get("demonstrated", {}).get("closest_min")
        if room and person:
            print(f"room {r['family']}/{r['scenario']}: closest approach min {room['closest_min']:.2f} m, "
                  f"median {room['closest_median']:.2f} m (the person on these starts: min "
                  f"{person['closest_min']:.2f}, median {person['closest_median']:.2f} m; "
                  f"in the demonstrations: min {shown if shown is None else round(shown, 2)} m)")
    for r in judged:       # beside the medians: the same starts compared (not a target)
        if "paired" in r and not r["refused"]:
            paired = r["paired"]
            print(f"paired time {r['family']}/{r['scenario']}: on the {paired['starts']} starts both "
                  f"finished, per start a median {paired['median_ratio']:.2f}x the person's, in total "
                  f"{paired['total_ratio']:.2f}x")
    families = sorted({r["family"] for r in rows})
    success = {f: [r["controller"]["success"] for r in rows if r["family"] == f] for f in families}
    worst = min(families, key=lambda f: (min(success[f]), np.mean(success[f])))
    print(f"worst family: {worst} (lowest row {min(success[worst]):.0%}, mean {np.mean(success[worst]):.1%})")
    learn_s = [r["learn"] for r in rows if r["scenario"] in SCENARIOS and r["demos"]]
    if learn_s:
        cpu = [i.get("learn_cpu_s", float("nan")) for i in learn_s]
        print(f"learning {DEMOS} demos (CIOC + check): CPU median {np.median(cpu):.1f} s, max "
              f"{max(cpu):.1f} s (target < 60 s)")
    for key in ("budget", "unbudgeted"):
        cycles = [r[key]["cycle_ms"] for r in rows if r[key]["cycle_ms"]["count"]]
        if cycles:
            count = sum(c["count"] for c in cycles)
            mean = sum(c["mean"] * c["count"] for c in cycles) / count
            print(f"controller cycle CPU time ({key}) over {count} cycles: mean {mean:.1f} ms, worst "
                  f"row p95 {max(c['p95'] for c in cycles):.1f} ms, "
                  f"{sum(c['over_100'] for c in cycles) / count:.1%} over 100 ms")


def main(argv=None) -> int:
    global OUT, DEMOS, VALIDATION_STARTS, TEST_SEED, PREDICTION
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phase", choices=["validate", "test", "table", "all", "room"], default="all",
                        help="room: add the closest approach to rows written without it")
    parser.add_argument("--families", nargs="*", choices=sorted(FAMILIES),
                        help="the families whose rows this process computes (default: all)")
    parser.add_argument("--scenarios", nargs="*", choices=SCENARIOS + LAYOUTS, default=SCENARIOS + LAYOUTS,
                        help="the rows this process computes (default: all; a layout row needs its "
                             "family's static reward)")
    parser.add_argument("--runs", type=int, default=100, help="held-out starts per test row (100)")
    parser.add_argument("--test-seed", type=int, default=TEST_SEED,
                        help=f"the held-out starts' seed ({TEST_SEED}; another seed draws starts no "
                             "earlier run has seen)")
    parser.add_argument("--prediction", choices=["scenario", "tracked"], default=PREDICTION,
                        help="the controller's obstacle future: the simulator's (as the node in the "
                             "simulator; default) or constant velocity from where it is now (as the "
                             "node on a robot)")
    parser.add_argument("--out", type=Path, help="result folder (resumable; default artifacts/bench/lfd)")
    parser.add_argument("--choice", nargs=2, metavar=("LEARNER", "CLONE"),
                        help="skip the validation phase: the learner candidate and cloning setting "
                             "for every fold (e.g. calibrated '[64, 64]|0.0001')")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: 4 demos, 2 validation starts (use with --out)")
    args = parser.parse_args(argv)
    OUT = args.out or OUT
    TEST_SEED, PREDICTION = args.test_seed, args.prediction
    if args.quick:
        DEMOS, VALIDATION_STARTS = 4, 2
    families = args.families or sorted(FAMILIES)
    started = time.monotonic()
    if args.phase == "validate" or (args.phase == "all" and not args.choice):
        print("validation rows (the choices; a different person per family and scenario):", flush=True)
        todo = families if args.phase == "validate" else sorted(FAMILIES)
        names = args.scenarios if args.phase == "validate" else SCENARIOS
        for family in todo:
            for name in names:
                validation_row(family, name)
    if args.phase in ("test", "all"):
        print(f"test rows ({args.runs} held-out starts each):", flush=True)
        for family in families:
            if args.choice:
                choice = tuple(args.choice)
                print(f"  {family} left out: learner '{choice[0]}', behaviour cloning {choice[1]} "
                      "(given: --choice)", flush=True)
            else:   # the other families' validation rows only (computed here when missing)
                validation = [validation_row(f, n) for f in sorted(FAMILIES) if f != family
                              for n in SCENARIOS]
                choice = choose(family, validation)
                print(f"  {family} left out: learner '{choice[0]}', behaviour cloning {choice[1]} "
                      f"(chosen on {', '.join(f for f in sorted(FAMILIES) if f != family)})", flush=True)
            for name in args.scenarios:
                test_row(family, name, choice, args.runs)
    if args.phase == "room":
        for path in sorted((OUT / "rows").glob("*.json")):
            if any(path.name.startswith(f + "__") for f in families) and any(
                    path.stem.endswith("__" + n) for n in args.scenarios):
                add_room(path)
    if args.phase in ("table", "all"):
        rows = [json.loads(p.read_text()) for p in sorted((OUT / "rows").glob("*.json"))]
        rows.sort(key=lambda r: (r["family"], (SCENARIOS + LAYOUTS).index(r["scenario"])))
        if rows:
            table(rows)
    print(f"({time.monotonic() - started:.0f} s; results in {OUT})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
