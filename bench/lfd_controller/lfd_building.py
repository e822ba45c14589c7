#!/usr/bin/env python3
"""lfd_controller in buildings: following a planned path among people, learned from people of a
family no setting was chosen on, driven on floor maps no setting was chosen on.

Floors: the training floor is the generated building (robot_sim.building, seed 0); the test
floor is the real Towne-Levine floor (../shared/data/maps; never used for any choice - the
real Levine 4th and 6th floors and the generated buildings of seeds 7 and 8 were the
development floors, so their figures are no held-out figures) or, when that folder is absent, a
larger generated building (seed 7). Scenes:
robot_sim.hallway.make_scene (start and goal 10-30 m apart along the halls here - the long
drives cost CPU; 2-8 people of every kind, one piece of clutter).

For each family F (of the lfd_controller.sim families; each but tangent, the development
family, left out of every choice: the feature set, the controller settings (hallway.
HALLWAY_DRIVING, HALLWAY_SAFETY) and the baselines' tuning were fixed without F's drives):
  * a new person of F gives demonstrations on training-floor scenes (only successful takes);
    the reward is learned (hallway.fit_hallway_reward), its pace set to the person's
    (calibrate_pace), the barrier margin to the person's room (room_margin) and checked
    with the controller in the loop on every demonstrated
    scene (hallway_acceptance: refused only for failing where the person succeeded; a refused
    reward scores 0 %) - lfd_controller.sim.teach_hallway's recipe (its `teach`);
  * on test-floor scenes the person drives, the learned controller drives with the node's 0.1 s
    cycle budget, and beside it behaviour cloning (the same demonstrations, size and L2 chosen
    on training-floor validation scenes), a social-force controller and a sampling (DWA-style)
    controller (each tuned on the same validation scenes: they learn nothing, so one tuning
    serves every family);
  * per row: success, collisions (wall / person / clutter), median time next to the person's
    own on the scenes both finished, median closest approach to people (edge to edge) next to
    the person's; the learned controller's cycle time (wall clock, whole cycle: scan points,
    waypoint, planning) over the scenes with 8 people.

Two time limits, both tables from the same drives: the scene's own (the path at 0.2 m/s plus
20 s) and the person's pace limit - the path at two thirds of the person's pace (their median
moving speed, which the learned controller cruises at) plus 20 s, never less than the scene's.
A person who drives at 0.2 m/s has no time left under the first for anybody in the way, and
neither has a controller that learned their pace; the second asks every controller in the row
to arrive at that person's pace with half as long again for the crowd. The person, the learned
controller and cloning drive until the pace limit; social force and DWA (shared by the
families) until twice the scene's limit.

Transfer: `--train levine_4th_good` has the person teach on that real floor instead (`--tests`
names the test maps); settings are still chosen on the generated building.

Resumable (artifacts/bench/lfd_building/<family>.json, or train_<floor>/ for a transfer run);
--phase table prints the table.
Run it as `OMP_NUM_THREADS=1 nice -n 10 python bench/lfd_controller/lfd_building.py`.
"""
import argparse
import json
import os
import sys
from pathlib import Path
from typing import Optional, Sequence

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from lfd_controller.baseline import BehaviourCloning  # noqa: E402
from lfd_controller.hallway import HALLWAY_SAFETY, TaskBuilder  # noqa: E402
from lfd_controller.hallway_baselines import SamplingController, SocialForceController, tune  # noqa: E402
from lfd_controller.sim import FAMILIES  # noqa: E402
from lfd_controller.sim.hallway_people import drive_figures, hallway_demonstration  # noqa: E402
from lfd_controller.sim.teach_hallway import (  # noqa: E402
    WAIT_LONG,
    drive_learner,
    family_person,
    scenes,
    teach,
)
from robot_common.maps import load_map  # noqa: E402
from robot_sim.building import generate_building  # noqa: E402
from robot_sim.hallway import drive  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "artifacts" / "bench" / "lfd_building"
MAPS = ROOT.parent / "shared" / "data" / "maps"
BC_GRID = {"hidden": ((64, 64),), "alpha": (1e-4, 1e-2)}
SF_GRID = {"speed": (0.4, 0.55), "push": (0.5, 1.5), "reach": (0.3, 0.6)}
DWA_GRID = {"v_max": (0.4, 0.55), "clearance_weight": (0.5, 2.0), "margin": (0.05, 0.15)}


def floors(train: str = "generated", tests: Optional[Sequence[str]] = None):
    """(choice floor grid, teaching floor grid, [(name, grid)] test floors). Settings are always
    chosen on the generated building; `train` names the floor the person teaches on (the
    generated building or a map in ../shared/data/maps: a transfer run), `tests` the test maps
    (default: Towne-Levine, the floor no setting was chosen on; Levine 6th when the person
    teaches on Towne-Levine)."""
    chosen = generate_building(0).grid
    taught = chosen if train == "generated" else load_map(MAPS / f"{train}.yaml")
    if MAPS.is_dir():
        names = tests or [n for n in ("towne_levine", "levine_6th") if n != train][:1]
        return chosen, taught, [(name, load_map(MAPS / f"{name}.yaml")) for name in names]
    return chosen, taught, [("generated_seed7", generate_building(7, rooms_per_side=7).grid)]


def out_dir() -> Path:
    """Where the rows go: one folder per teaching floor."""
    base = Path(ARGS.out) if ARGS.out else OUT
    return base if ARGS.train == "generated" else base / f"train_{ARGS.train}"


def view_policy(act_on_task, scene):
    """A robot_sim drive policy from a controller acting on the HallwayTask of each cycle."""
    tasks = TaskBuilder(scene.path, lookahead=HALLWAY_SAFETY["lookahead"])

    def policy(state, t, seen):
        return act_on_task(state, t, tasks(state, t, seen.angles, seen.ranges, seen.people,
                                           seen.velocities))
    return policy


# The pace limit (module docstring): the path at PACE_SHARE of the person's pace plus 20 s;
# the shared baselines drive until BASELINE_LIMIT times the scene's limit.
PACE_SHARE, BASELINE_LIMIT = 2.0 / 3.0, 2.0


def pace_limit(scene, pace: float) -> float:
    """The time (s) allowed at the person's `pace` (m/s): never less than the scene's."""
    return max(scene.max_time, scene.length / (PACE_SHARE * pace) + 20.0)


def drive_baseline(scene, controller, max_time=None):
    return drive_figures(drive(scene, view_policy(controller.act, scene), max_time=max_time))


def drive_cloning(scene, policy, max_time=None):
    return drive_figures(drive(scene, view_policy(policy.predict, scene), max_time=max_time))


def shared_baselines(scene, sf, dwa):
    """The social-force and sampling drives of a test scene: they learn nothing, so each
    family's run drives the same scene the same way; the first to get there saves them."""
    path = out_dir() / "baseline_drives" / (scene.name.replace("/", "_") + ".json")
    if path.exists():
        return json.loads(path.read_text())
    longest = BASELINE_LIMIT * scene.max_time
    drives = {"social_force": drive_baseline(scene, sf, longest),
              "sampling": drive_baseline(scene, dwa, longest)}
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.getpid()}.part")
    partial.write_text(json.dumps(drives, default=float))
    partial.replace(path)
    return drives


def success_score(runs):
    return np.mean([r["success"] for r in runs]) - 0.01 * np.nanmedian(
        [r["time"] if r["success"] else 400.0 for r in runs]) / 100.0


def tuned_baselines(choice_grid):
    """The social-force and sampling controllers tuned on the validation scenes (the tuning of
    an earlier run of this folder is reused: they learn nothing, so it does not change)."""
    path = out_dir() / "baselines.json"
    validation = scenes(choice_grid, "validation", range(500, 503))
    if path.exists():
        saved = json.loads(path.read_text())
        return (SocialForceController(**saved["social_force"]),
                SamplingController(**saved["sampling"]), validation)
    sf, sf_table = tune(SocialForceController, SF_GRID,
                        lambda c: success_score([drive_baseline(s, c) for s in validation]))
    dwa, dwa_table = tune(SamplingController, DWA_GRID,
                          lambda c: success_score([drive_baseline(s, c) for s in validation]))
    path.write_text(json.dumps({"social_force": sf.get_params(), "sampling": dwa.get_params(),
                                "tables": {"social_force": sf_table, "sampling": dwa_table}},
                               indent=1))
    return sf, dwa, validation


def family_row(family, train_grid, tests, sf, dwa, validation, demos_wanted):
    person = family_person(family)
    taught = teach(person, scenes(train_grid, "train", range(100, 100 + 3 * demos_wanted)),
                   demos_wanted)
    reward, margin, verdict, step_windows = (taught.reward, taught.margin, taught.verdict,
                                             taught.step_windows)
    cloning, best = None, -np.inf
    for hidden in BC_GRID["hidden"]:
        for alpha in BC_GRID["alpha"]:
            policy = BehaviourCloning(hidden, 2000, 0, alpha).fit(step_windows)
            score = success_score([drive_cloning(s, policy) for s in validation[:2]])
            if score > best:
                cloning, best = policy, score
    rows, pace = [], float(np.median(taught.speeds))
    for floor, grid in tests:
        for index, scene in enumerate(scenes(grid, floor, range(2000, 2000 + ARGS.scenes))):
            longest = pace_limit(scene, pace)
            row = {"floor": floor, "scene": scene.name, "people": len(scene.people),
                   "length": round(scene.length, 1), "limit": scene.max_time,
                   "pace_limit": longest}
            row["person"] = drive_figures(hallway_demonstration(person, scene, longest)[0])
            row["learned"] = drive_learner(scene, reward, margin=margin, max_time=longest)
            if index < ARGS.baseline_scenes:
                row["cloning"] = drive_cloning(scene, cloning, longest)
                row.update(shared_baselines(scene, sf, dwa))
            rows.append(row)
            print(f"{family} {scene.name} people={row['people']} "
                  + " ".join(f"{k}={row[k]['success']}/{row[k]['collision']}/{row[k]['time']:.0f}"
                             for k in METHODS if k in row), flush=True)
    return {"family": family, "demos": len(taught.demo_scenes), "windows": len(taught.windows),
            "pace": pace,
            "margin": margin, "learn_cpu_s": taught.learn_cpu, "acceptance": verdict,
            "weights": dict(zip(reward.features.names, map(float, reward.weights))), "rows": rows}


METHODS = ("person", "learned", "cloning", "social_force", "sampling")


def within(run, row, limit):
    """The drive `run` of `row` cut at `limit` ("limit": the scene's, "pace_limit": the
    person's pace): (reached the goal in time without collision, collided in time)."""
    allowed = row[limit] + 1e-6
    return (bool(run["success"] and run["time"] <= allowed),
            run["collision"] is not None and run.get("ended", 0.0) <= allowed)


def family_cells(data, limit):
    """The table cells of one family's rows under `limit`."""
    rows = data["rows"]
    cells = []
    for method in METHODS:
        runs = [within(r[method], r, limit) for r in rows if method in r]
        cells.append(f"{sum(ok for ok, _ in runs)}/{len(runs)} "
                     f"({sum(hit for _, hit in runs)} coll.)")
    both = [r for r in rows if within(r["learned"], r, limit)[0]
            and within(r["person"], r, limit)[0]]
    times = {m: np.median([r[m]["time"] for r in both]) if both else np.nan
             for m in ("learned", "person")}
    ratio = f"{times['learned'] / times['person']:.2f}x" if both else "-"
    room = (f"{np.median([r['learned']['closest'] for r in both]):.2f} vs "
            f"{np.median([r['person']['closest'] for r in both]):.2f}" if both else "-")
    verdict = "accepted" if data["acceptance"]["accepted"] else \
        "refused: " + "; ".join(data["acceptance"]["failures"])
    return (f"| {data['family']} | {len(rows)} | " + " | ".join(cells)
            + f" | {ratio} | {room} | {verdict} |")


def table():
    families = [json.loads(path.read_text()) for path in sorted(out_dir().glob("*.json"))
                if path.name != "baselines.json"]
    for limit, title in (("limit", "the scene's time limit (the path at 0.2 m/s plus 20 s)"),
                         ("pace_limit", "the person's pace limit (the path at two thirds of "
                                        "the person's pace plus 20 s)")):
        print(f"\nWithin {title}:\n")
        print("| family | floor drives | " + " | ".join(METHODS) + " | learned time x person | "
              "closest learned vs person (median m) | acceptance |")
        print("|" + " --- |" * (len(METHODS) + 5))
        for data in families:
            if all(limit in r for r in data["rows"]):
                print(family_cells(data, limit))
    paces = ", ".join(f"{d['family']} {d['pace']:.2f}" for d in families if "pace" in d)
    if paces:
        print(f"\nthe people's paces (m/s): {paces}")
    cycles8, recovered = [], []
    for data in families:
        rows = data["rows"]
        cycles8 += [c for r in rows if r["people"] == 8 for c in r["learned"]["cycles"]]
        recovered += [r["learned"] for r in rows if "recoveries" in r["learned"]]
    for kind in ("detours", "backing_up", "giving_way"):
        used = [r for r in recovered if r["recoveries"][kind]]
        if used:
            print(f"learned drives with {kind}: {len(used)} of {len(recovered)} "
                  f"({sum(r['success'] for r in used)} of them reached the goal)")
    truth = [r["giving_way"] for r in recovered if "giving_way" in r]
    if truth:
        total = {key: sum(t[key] for t in truth) for key in truth[0]}
        print(f"giving way against the simulator's truth ({len(truth)} drives): "
              f"{total['right']} with someone near waiting for the robot, {total['wrong']} "
              f"without; of {total['standoffs']} standoffs (someone near and in front waiting "
              f"while the robot stood held up {WAIT_LONG:g} s), {total['missed']} without "
              f"giving way")
    if cycles8:
        print(f"\ncycle time with 8 people, 0.1 s budget: {len(cycles8)} cycles, p50 "
              f"{np.percentile(cycles8, 50) * 1000:.0f} ms, p99 {np.percentile(cycles8, 99) * 1000:.0f} ms, "
              f"max {max(cycles8) * 1000:.0f} ms")


def main():
    out_dir().mkdir(parents=True, exist_ok=True)
    if ARGS.phase == "table":
        table()
        return 0
    choice_grid, train_grid, tests = floors(ARGS.train, ARGS.tests)
    sf, dwa, validation = tuned_baselines(choice_grid)
    print(f"tuned: social force {sf.get_params()}, sampling {dwa.get_params()}", flush=True)
    for family in ARGS.families:
        path = out_dir() / f"{family}.json"
        if path.exists():
            continue
        row = family_row(family, train_grid, tests, sf, dwa, validation, ARGS.demos)
        path.write_text(json.dumps(row, indent=1, default=float))
    table()
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--phase", choices=("run", "table"), default="run")
    parser.add_argument("--families", nargs="+", default=sorted(FAMILIES))
    parser.add_argument("--demos", type=int, default=6, help="demonstrations per family")
    parser.add_argument("--scenes", type=int, default=3, help="test scenes per test floor")
    parser.add_argument("--baseline-scenes", type=int, default=1000,
                        help="the baselines (cloning, social force, sampling) drive only the "
                             "first this many test scenes per floor (they cost CPU)")
    parser.add_argument("--train", default="generated",
                        help="the floor the person teaches on: generated or a map name (transfer)")
    parser.add_argument("--tests", nargs="+", default=None, help="test map names")
    parser.add_argument("--out", default="", help="the results folder (default: "
                        "artifacts/bench/lfd_building; the baselines' tuning and drives are "
                        "reused from it when there)")
    ARGS = parser.parse_args()
    sys.exit(main())
