#!/usr/bin/env python3
"""Errands through a floor at busy and quiet times: does the crowd-aware planner (errand_nav)
meet fewer people in the rush than the shortest path, and is it no slower when the halls are
quiet? Outcomes are measured against the people simulator's truth, not the planner's own
expectation.

Floors: the planner's setting (person_cost) is chosen on the generated building (robot_sim,
seed 0); the report floors are the real Levine Hall 4th and 6th floor maps (../shared/data/maps,
never used for any choice; skipped with a message when that folder is absent). Truth: robot_sim's
people densities over the week (the simulator traffic_gp's truth comes from): busy main halls,
rushes in the minutes before classes start on the hour. Crowd model: traffic_gp's tuned baseline
forecast (traffic_gp.quick.BaselineForecast: FreMEn or the binned mean, tuned on held-out days),
fitted on two weeks of simulated robots' counts (weekday_views, rows merged per cell and 5
minutes, as bench/traffic_gp does); the GP is not fitted here (tens of minutes per floor).

Errands: start and goal at random clear spots 15 m or more apart, on weekdays of the week after
the training weeks; busy: leaving 7-13 minutes before a class hour (10:00-17:00); quiet: leaving
20:00-21:30. Plans per errand (errand_nav.planning.CrowdPlanner, the same settings):
  shortest   on a quiet forecast (no crowd model: shortest travel time);
  crowd      on the crowd model's forecast (every 2 minutes over the 15-minute look-ahead);
  truth      on the simulator's true densities (the best a forecast could do).
Each plan is driven among simulated individual people (robot_sim.crowd, the hour's densities;
bench/errand_nav/crowd_drive.py: a pure-pursuit follower that passes, slows and waits for people,
by default; `--driver learned`: lfd_controller's learned controller instead, HallwayController
in path mode with a taught hallway reward, bench/errand_nav/learned_drive.py, among the same
people; its
optimisation costs 7-12 CPU-ms per 0.1 s step on average (5-60 CPU-s a drive), so run few
errands; `--driver both`: both on
the same plans and people). Every driver has the same time (crowd_drive.time_limit: the path
at 0.15 m/s plus 60 s). Per plan and time: success (goal reached in that time, no collision),
the share reached within 3 x the plan's expected time on the true densities,
collisions, people met (distinct people within meet_radius of the robot at some time), travel
time, path length.

  python bench/errand_nav/errands.py [--quick] [--errands N] [--floors NAMES]
      [--driver follower|learned|both] [--reward FILE] [--plans shortest crowd truth]
      [--budget SECONDS] [--errand-seed N]
  python bench/errand_nav/errands.py --pool RUN.json [RUN.json ...]   (tables of runs pooled)

The learned driver's reward: `--reward FILE`, else taught once into
artifacts/bench/errand_nav_reward.yaml (lfd_controller.sim.teach_hallway, family sampling_mpc
on the generated building, 3 demonstrations; about 35 CPU-s) and reused when there.
"""
import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Optional

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import crowd_drive  # noqa: E402
import learned_drive  # noqa: E402

from errand_nav.forecast import DensityForecast  # noqa: E402
from errand_nav.planning import CrowdPlanner, PlannerSettings  # noqa: E402
from robot_common.gridplan import NoPathError  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.queries import CrowdQueries  # noqa: E402
from traffic_gp.quick import BaselineForecast  # noqa: E402
from traffic_gp.sim.evaluation import simulator_for, weekday_views  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "artifacts" / "bench"
MAPS = Path(os.environ.get("SHARED_DATA_DIR", str(ROOT.parent / "shared" / "data"))) / "maps"
PLANS = ("shortest", "crowd", "truth")
DRIVERS = ("follower", "learned")
REWARD = OUT / "errand_nav_reward.yaml"
SLOW = 3.0              # x the plan's expected time on the true densities: "slow" arrivals
KINDS = ("busy", "quiet")
STEP_MINUTES, LOOK_MINUTES = 2.0, 15.0
PERSON_COSTS = (3.0, 10.0, 30.0)


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


class FloorRun:
    """A floor with its people simulator, the crowd model fitted on its robots' counts and
    its clearance for driving."""

    def __init__(self, spec: str, views: int, seed: int):
        started = cpu_seconds()
        self.sim = simulator_for(spec, 0.5, seed=seed)
        self.grid = self.sim.cells.grid
        rows = Observations.from_views(self.sim.cells, weekday_views(self.sim, views, weeks=2))
        self.model = BaselineForecast().fit(rows.compress(5 / 60.0, None), self.sim.cells)
        self.queries = CrowdQueries(self.model, self.sim.cells)
        self.floor = crowd_drive.Floor(self.grid)
        log(f"  {spec}: {views} views, crowd model {self.model.name_} "
            f"{self.model.setting_} in {cpu_seconds() - started:.0f} CPU-s")

    def forecast(self, depart_hours: float, source: str) -> DensityForecast:
        cells = self.sim.cells
        if source == "shortest":
            return DensityForecast.quiet(cells.coarse)
        hours = depart_hours + np.arange(0.0, LOOK_MINUTES + 1e-9, STEP_MINUTES) / 60.0
        values = self.queries.densities(hours) if source == "crowd" else self.sim.density(hours)
        grids = np.zeros((hours.size,) + cells.coarse.cells.shape)
        grids[:, cells.rows, cells.cols] = values
        return DensityForecast(cells.coarse.origin[:2], cells.cell_size, hours * 3600.0, grids)

    def errands(self, count: int, kind: str, rng) -> list:
        """(start, goal, depart hours) of `count` errands at `kind` times."""
        planner = CrowdPlanner(self.grid, PlannerSettings())
        clear = np.argwhere(planner.search.distance >= 0.5)
        spots = np.column_stack(planner.search.coarse.cell_to_world(clear[:, 0], clear[:, 1]))
        chosen = []
        while len(chosen) < count:
            start, goal = spots[rng.integers(len(spots), size=2)]
            if np.hypot(*(goal - start)) < 15.0:
                continue
            try:
                planner.plan(start, goal, 0.0, DensityForecast.quiet(self.grid))
            except NoPathError:
                continue
            day = 14 + int(rng.integers(5))
            if kind == "busy":
                hour = int(rng.integers(10, 18)) - 1 + rng.uniform(47, 53) / 60.0
            else:
                hour = 20.0 + rng.uniform(0.0, 1.5)
            chosen.append((start, goal, day * 24.0 + hour))
        return chosen


def run_errand(run: FloorRun, planners: dict, errand, seed: int, drivers: dict) -> dict:
    """Plan with each planner on its forecast, drive each plan among the same people with
    each driver: {driver: {plan: row}}."""
    start, goal, depart = errand
    truth = run.forecast(depart, "truth")
    rows = {driver: {} for driver in drivers}
    for name, (planner, source) in planners.items():
        began = cpu_seconds()
        path = planner.plan(start, goal, depart * 3600.0, run.forecast(depart, source))
        plan_cpu = cpu_seconds() - began
        expected = planner.evaluate(path.points, depart * 3600.0, truth)
        for driver, learned in drivers.items():
            began = cpu_seconds()
            if learned is None:
                outcome = crowd_drive.drive(run.floor, run.sim, path.points, depart,
                                            speed=planner.settings.free_speed,
                                            meet_radius=planner.settings.meet_radius, seed=seed)
            else:
                outcome = learned.drive(run.floor, run.grid, run.sim, path.points, depart,
                                        meet_radius=planner.settings.meet_radius, seed=seed,
                                        limit=crowd_drive.time_limit(path.length))
            row = {"success": outcome.success, "reached": outcome.reached,
                   "in_time": outcome.success and outcome.seconds <= SLOW * expected.duration,
                   "collisions": outcome.collisions, "wall": outcome.wall, "met": outcome.met,
                   "seconds": outcome.seconds, "length": path.length,
                   "expected_people": expected.people_met, "expected_seconds": expected.duration,
                   "plan_cpu": plan_cpu, "drive_cpu": cpu_seconds() - began}
            if learned is not None:
                row.update(learned_drive.summary([outcome]), status=outcome.status,
                           progress=outcome.progress,
                           coarse_wall_steps=outcome.coarse_wall_steps,
                           near_still_max=max(outcome.near_still, default=0),
                           around_still_max=max(outcome.around_still, default=0))
            rows[driver][name] = row
    return rows


def summarise(results: list) -> dict:
    """Per plan: errands, success share, collisions, mean people met, mean time and length."""
    table = {}
    for name in results[0]:
        rows = [r[name] for r in results]
        ok = [r for r in rows if r["success"]]
        table[name] = {"errands": len(rows), "success": float(np.mean([r["success"] for r in rows])),
                       "in_time": float(np.mean([r.get("in_time", r["success"]) for r in rows])),
                       "collisions": int(sum(r["collisions"] for r in rows)),
                       "met": float(np.mean([r["met"] for r in rows])),
                       "expected_people": float(np.mean([r["expected_people"] for r in rows])),
                       "seconds": float(np.mean([r["seconds"] for r in ok])) if ok else float("nan"),
                       "length": float(np.mean([r["length"] for r in rows])),
                       "plan_cpu": float(np.mean([r["plan_cpu"] for r in rows])),
                       "drive_cpu": float(np.sum([r.get("drive_cpu", 0.0) for r in rows]))}
        if "blocked" in rows[0]:    # the learned driver: how it stood still
            still = [r for r in rows if r["still_seconds"] > 0]
            table[name].update(
                blocked=int(sum(r["blocked"] for r in rows)),
                coarse_wall_steps=int(sum(r.get("coarse_wall_steps", 0) for r in rows)),
                timeouts=int(sum(not r["reached"] and not r["blocked"] and not r["wall"]
                                 for r in rows)),
                still_seconds=float(np.mean([r["still_seconds"] for r in rows])),
                near_still_mean=float(np.mean([r["near_still_mean"] for r in still]))
                if still else float("nan"),
                around_still_mean=float(np.mean([r["around_still_mean"] for r in still]))
                if still else float("nan"),
                around_still_max=int(max([r["around_still_max"] for r in rows], default=0)),
                cycle_cpu_ms_mean=float(np.mean([r["cycle_cpu_ms_mean"] for r in rows])),
                cycle_cpu_ms_p95=float(np.max([r["cycle_cpu_ms_p95"] for r in rows])))
    both = [r for r in results if all(r[name]["success"] for name in r)]
    for name in results[0]:     # time over the errands every plan finished (paired)
        table[name]["seconds_paired"] = float(np.mean([r[name]["seconds"] for r in both])) \
            if both else float("nan")
    return table


def floor_table(run: FloorRun, planners: dict, count: int, seed: int,
                drivers: Optional[dict] = None) -> dict:
    """{kind: {summary, errands}} of the one driver, or {driver: that} when `drivers` (name:
    None for the follower, a LearnedDriver) are given."""
    rng = np.random.default_rng(seed)
    chosen = drivers if drivers is not None else {"follower": None}
    tables = {driver: {} for driver in chosen}
    for kind in KINDS:
        results = {driver: [] for driver in chosen}
        for number, errand in enumerate(run.errands(count, kind, rng)):
            rows = run_errand(run, planners, errand, seed * 1000 + number, chosen)
            for driver, plans in rows.items():
                results[driver].append(plans)
                log(f"    {kind} errand {number + 1}/{count} ({driver}): " + ", ".join(
                    f"{name} met {row['met']} in {row['seconds']:.0f} s"
                    + ("" if row["success"] else " FAILED" + (
                        " (wall)" if row["wall"] else
                        f" ({row['status']}, {row['progress']:.0%} of the path)" if "status" in row
                        else ""))
                    + (f" [stood {row['still_seconds']:.0f} s, {row['around_still_mean']:.1f} "
                       f"people within 3 m then; collisions {row['collisions']}; "
                       f"{row['coarse_wall_steps']} steps inside the 0.1 m map's walls; "
                       f"{row['drive_cpu']:.0f} CPU-s]" if "status" in row else "")
                    for name, row in plans.items()))
        for driver in chosen:
            tables[driver][kind] = {"summary": summarise(results[driver]),
                                    "errands": results[driver]}
    return tables if drivers is not None else tables["follower"]


def choose_person_cost(run: FloorRun, count: int, seed: int) -> tuple:
    """On the tuning floor: among the person_costs whose crowd-aware plans are no slower than
    the shortest path when quiet (mean time of the errands every plan finished, within 2%) and
    at most 15% slower in the busy hours, the one meeting the fewest people in the busy hours
    (the smallest candidate when none qualifies)."""
    planners = {"shortest": (CrowdPlanner(run.grid, PlannerSettings()), "shortest")}
    for cost in PERSON_COSTS:
        planners[f"crowd {cost:g} s"] = (
            CrowdPlanner(run.grid, PlannerSettings(person_cost=cost)), "crowd")
    tables = floor_table(run, planners, count, seed)

    def ratio(kind, cost):
        table = tables[kind]["summary"]
        return table[f"crowd {cost:g} s"]["seconds_paired"] / table["shortest"]["seconds_paired"]
    allowed = [c for c in PERSON_COSTS if ratio("quiet", c) <= 1.02 and ratio("busy", c) <= 1.15]
    chosen = min(allowed or PERSON_COSTS[:1],
                 key=lambda c: tables["busy"]["summary"][f"crowd {c:g} s"]["met"])
    return chosen, tables


PLAN_COLUMNS = (("errands", "{errands}"), ("success", "{success:.0%}"),
                (f"within {SLOW:g} x expected", "{in_time:.0%}"),
                ("collisions", "{collisions}"), ("people met", "{met:.1f}"),
                ("(expected)", "{expected_people:.1f}"), ("travel s", "{seconds:.0f}"),
                ("(paired)", "{seconds_paired:.0f}"), ("length m", "{length:.1f}"),
                ("plan CPU s", "{plan_cpu:.2f}"))
STOP_COLUMNS = (("blocked (20 s held up)", "{blocked}"), ("timeouts", "{timeouts}"),
                ("s stood still per errand", "{still_seconds:.0f}"),
                ("people within 1.5 m / 3 m while still (mean)",
                 "{near_still_mean:.1f} / {around_still_mean:.1f}"),
                ("within 3 m (max)", "{around_still_max}"),
                ("cycle CPU ms (mean, p95 max)", "{cycle_cpu_ms_mean:.1f}, {cycle_cpu_ms_p95:.1f}"),
                ("steps inside the 0.1 m map's walls", "{coarse_wall_steps}"),
                ("drive CPU s", "{drive_cpu:.0f}"))


def print_rows(tables: dict, columns) -> None:
    """A markdown table: a row per time and plan, the (header, format) columns of its summary."""
    print("| time | plan | " + " | ".join(header for header, _ in columns) + " |")
    print("|---" * (len(columns) + 2) + "|")
    for kind, table in tables.items():
        for name, row in table["summary"].items():
            print(f"| {kind} | {name} | " + " | ".join(f.format(**row) for _, f in columns) + " |")


def print_table(title: str, tables: dict) -> None:
    print(f"\n{title}")
    print_rows(tables, PLAN_COLUMNS)
    busy, quiet = tables["busy"]["summary"], tables["quiet"]["summary"]
    if "blocked" in next(iter(busy.values())):
        print_rows(tables, STOP_COLUMNS)
    crowd = next((name for name in busy if name.startswith("crowd")), None)
    if crowd is None or "shortest" not in busy:
        return
    for kind, key in (("busy", "met"), ("quiet", "seconds")):
        pairs = [(r[crowd][key], r["shortest"][key]) for r in tables[kind]["errands"]
                 if r[crowd]["success"] and r["shortest"]["success"]]
        gap = np.array([a - b for a, b in pairs], float).reshape(-1)
        if not gap.size:
            print(f"{kind}: no errand both plans finished")
            continue
        half = 1.96 * gap.std(ddof=1) / np.sqrt(gap.size) if gap.size > 1 else float("nan")
        print(f"{kind}: {key} crowd-aware - shortest per errand {gap.mean():+.2f} +- {half:.2f} "
              f"(95% interval, {gap.size} errands both finished)")
    paired = [table[name]["seconds_paired"] for table in (busy, quiet) for name in (crowd, "shortest")]
    if not all(np.isfinite(paired)):
        return
    print(f"crowd-aware / shortest: people met in the busy hours "
          f"{busy[crowd]['met'] / max(busy['shortest']['met'], 1e-9):.2f}x, travel time when "
          f"quiet {quiet[crowd]['seconds_paired'] / quiet['shortest']['seconds_paired']:.3f}x "
          f"(busy {busy[crowd]['seconds_paired'] / busy['shortest']['seconds_paired']:.3f}x)")


def learned_drivers(args) -> dict:
    """{driver: None (the follower) or a LearnedDriver} of `--driver`, the reward taught
    first when need be ({} when teaching failed)."""
    reward = args.reward or str(REWARD)
    if args.reward is None and not REWARD.is_file():
        from lfd_controller.sim.teach_hallway import main as teach
        began = cpu_seconds()
        OUT.mkdir(parents=True, exist_ok=True)
        if teach(["--family", "sampling_mpc", "--floor", "generated:0", "--demos", "3",
                  "--out", reward]):
            return {}
        log(f"taught {REWARD.relative_to(ROOT)} in {cpu_seconds() - began:.0f} CPU-s")
    learned = learned_drive.LearnedDriver(reward, budget=args.budget or None)
    shown = REWARD.relative_to(ROOT) if args.reward is None else reward
    print(f"learned driver: reward {shown}, barrier margin "
          f"{learned.safety['barrier_margin']:.2f} m, cycle budget "
          f"{args.budget or 'none'}")
    return {"learned": learned} if args.driver == "learned" else \
        {"follower": None, "learned": learned}


def pool(files) -> int:
    """Print the tables of several runs' JSON files with their errands pooled."""
    reports = [json.loads(Path(name).read_text()) for name in files]
    for floor, first in reports[0].items():
        if not isinstance(first, dict) or "busy" in first and "summary" not in first["busy"]:
            continue
        drivers = first if "busy" not in first else {"follower": first}
        for driver in drivers:
            tables = {}
            for kind in KINDS:
                errands = [row for report in reports for row in (
                    report[floor][driver] if "busy" not in report[floor] else report[floor]
                )[kind]["errands"]]
                tables[kind] = {"summary": summarise(errands), "errands": errands}
            print_table(f"{floor}, driven by the {driver}: {len(files)} runs pooled", tables)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a small smoke run")
    parser.add_argument("--errands", type=int, default=None, help="errands per floor and time")
    parser.add_argument("--floors", default=None,
                        help="comma-separated Levine floors (default: levine_4th_good,levine_6th; "
                             "'' for none)")
    parser.add_argument("--skip-tuning", action="store_true",
                        help="use the default person_cost (as --quick does)")
    parser.add_argument("--driver", choices=DRIVERS + ("both",), default="follower",
                        help="who drives the plans: the pure-pursuit follower (crowd_drive), the "
                             "learned controller (learned_drive) or both on the same people; "
                             "learned skips the tuning (the default person_cost)")
    parser.add_argument("--reward", default=None,
                        help="the learned driver's reward file (default: taught once into "
                             "artifacts/bench/errand_nav_reward.yaml)")
    parser.add_argument("--plans", nargs="+", choices=PLANS, default=list(PLANS),
                        help="the plans to drive")
    parser.add_argument("--budget", type=float, default=0.0,
                        help="the learned controller's cycle budget in s (0: none, the default: "
                             "results independent of the machine's load; the node runs 0.1)")
    parser.add_argument("--errand-seed", type=int, default=20,
                        help="the errands' seed on the first report floor (+1 per floor)")
    parser.add_argument("--pool", nargs="+", default=None, metavar="JSON",
                        help="print the tables of these runs' files pooled (the same floors, "
                             "drivers and plans; nothing driven)")
    args = parser.parse_args(argv)
    if args.pool:
        return pool(args.pool)
    drivers = None if args.driver == "follower" else learned_drivers(args)
    if drivers == {}:
        return 1
    count = args.errands or (3 if args.quick else 40)
    views = 3000 if args.quick else 20000
    print(f"errand_nav errands: {count} errands per floor and time, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f} at start", flush=True)
    report = {"errands_per_time": count, "views": views}
    if args.quick or args.skip_tuning or drivers is not None:
        chosen, tuned = PlannerSettings().person_cost, None
    else:
        log("tuning floor (generated building, seed 0):")
        chosen, tuned = choose_person_cost(FloorRun("generated:0", views, seed=1), count, seed=2)
        print_table("Tuning floor (generated building): person_cost candidates", tuned)
        report["tuning"] = tuned
    default = PlannerSettings().person_cost
    print(f"person_cost chosen on the generated building: {chosen:g} s (the default: {default:g} s)")
    settings = PlannerSettings(person_cost=chosen)
    names = ["levine_6th"] if args.quick else ["levine_4th_good", "levine_6th"]
    names = names if args.floors is None else [name for name in args.floors.split(",") if name]
    if not MAPS.is_dir():
        print(f"SKIPPED the Levine floors: no map folder {MAPS} (../shared/data/maps is absent)")
        names = []
    for number, name in enumerate(names):
        log(f"report floor {name}:")
        run = FloorRun(str(MAPS / f"{name}.yaml"), views, seed=10 + number)
        planners = {plan: (CrowdPlanner(run.grid, settings), "shortest" if plan == "shortest"
                           else plan) for plan in args.plans}
        tables = floor_table(run, planners, count, seed=args.errand_seed + number,
                             drivers=drivers)
        if drivers is None:
            print_table(f"{name} (person_cost {chosen:g} s)", tables)
        else:
            for driver, table in tables.items():
                print_table(f"{name} (person_cost {chosen:g} s), driven by the {driver}", table)
        report[name] = tables
    report.update(cpu_seconds=cpu_seconds(), finished=time.strftime("%Y-%m-%d %H:%M:%S"))
    OUT.mkdir(parents=True, exist_ok=True)
    stem = "errand_nav" if drivers is None else f"errand_nav_{args.driver}"
    floors = "" if args.floors is None else "_" + "_".join(names)
    floors += "" if args.errand_seed == 20 else f"_seed{args.errand_seed}"
    path = OUT / (f"{stem}_quick{floors}.json" if args.quick else f"{stem}{floors}.json")
    path.write_text(json.dumps(report, indent=1, default=float))
    print(f"CPU {cpu_seconds():.0f} s (user+sys of the process); wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
