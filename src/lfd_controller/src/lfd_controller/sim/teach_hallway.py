"""teach_hallway: a path-mode (hallway) reward learned from a simulated person's drives on a
building floor, checked with the controller in the loop and saved for reward_controller.

    python -m lfd_controller.sim.teach_hallway --family tangent --floor generated:0 --demos 5 \\
        --out reward.yaml [--seed 0] [--layout hall|loop] [--length 10 30] [--accept-anyway]

The recipe is the building benchmark's (bench/lfd_controller/lfd_building.py imports it from
here): scenes on the floor (robot_sim.hallway.make_scene, start and goal `--length` m apart
along the halls, 2-8 people, one piece of clutter); a person of the family
(sim.hallway_people.HallwayDriver) drives them until `--demos` drives succeeded (at most 3 x
`--demos` scenes); CIOC on their 4 s windows (hallway.fit_hallway_reward), the pace set to the
person's median moving speed (calibrate_pace), the barrier margin to the person's room
(room_margin); then the controller (no cycle budget: the verdict does not depend on how busy
the machine is) drives every demonstrated scene and `hallway_acceptance` refuses the reward
only for failing where the person succeeded. The file (learning.save_reward) holds the weights
and `info`: the family, floor, demonstrations, windows, learning seconds, the verdict and
`controller: {barrier_margin}` (reward_controller applies it: RewardControllerParams.
SAVED_SETTINGS). Progress on stderr; exit 1 with one `ERROR:` line when no drive succeeded or
the reward is refused (`--accept-anyway` saves a refused reward, saying so in the file).
"""
import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from lfd_controller.errors import LfdError
from lfd_controller.hallway import (
    HALLWAY_SAFETY,
    HallwayController,
    calibrate_pace,
    fit_hallway_reward,
    hallway_acceptance,
    hallway_windows,
    room_margin,
)
from lfd_controller.learning import save_reward
from lfd_controller.sim.families import FAMILIES
from lfd_controller.sim.hallway_people import HallwayDriver, drive_figures, hallway_demonstration
from robot_common.maps import GridMap, load_map
from robot_common.unicycle import Unicycle
from robot_sim.building import generate_building
from robot_sim.hallway import HallwayScene, drive, make_scene

__all__ = ["LENGTH", "WAIT_LONG", "floor_grid", "scenes", "drive_learner", "WaitsForRobot", "Teaching",
           "teach", "main"]

LENGTH = (10.0, 30.0)   # start to goal along the halls (m): longer drives cost CPU
FIRST_SCENE = 100       # the training scenes' first seed (the benchmark's)
TRIES = 3               # scenes tried per wanted demonstration
# The truth about giving way: a walker holding for the robot (Walker.yield_to) within WAIT_NEAR m
# of it waits for it; waits as long as the controller is held up before it recovers count.
WAIT_NEAR, WAIT_LONG = 2.0, HALLWAY_SAFETY["replan_after"]
STANDING = 0.05         # m/s: the robot stands
LAYOUTS = ("hall", "loop")


def floor_grid(floor: str, layout: str = "hall") -> GridMap:
    """The floor map of `generated:SEED` (robot_sim.building.generate_building; layout "loop":
    with its second way round, `loop=True`) or of a map_server .yaml file; LfdError naming the
    value when it is neither."""
    if layout not in LAYOUTS:
        raise LfdError(f"--layout must be one of {LAYOUTS}, got {layout!r}")
    if floor.startswith("generated:"):
        try:
            seed = int(floor.split(":", 1)[1])
        except ValueError as err:
            raise LfdError(f"--floor generated:SEED needs an integer seed, got {floor!r}") from err
        return (generate_building(seed, loop=True) if layout == "loop" else
                generate_building(seed)).grid
    if layout != "hall":
        raise LfdError(f"--layout {layout} applies to a generated floor, not to {floor}")
    if not floor.endswith(".yaml"):
        raise LfdError(f"--floor must be generated:SEED or a map_server .yaml file, got {floor!r}")
    try:
        return load_map(floor)
    except Exception as err:  # noqa: BLE001 - any unreadable map is the user's bad input
        raise LfdError(f"cannot load the floor map {floor}: {err}") from err


def scenes(grid: GridMap, name: str, seeds: Sequence[int], people: Optional[int] = None,
           length: Sequence[float] = LENGTH) -> List[HallwayScene]:
    """Scenes on `grid`, one per seed: `people` people (default 2 + seed % 7) and one clutter."""
    return [make_scene(grid, seed, people=people or 2 + seed % 7, clutter=1, length=length,
                       name=f"{name}/{seed}") for seed in seeds]


def drive_learner(scene: HallwayScene, reward, budget: Optional[float] = 0.1,
                  margin: float = HALLWAY_SAFETY["barrier_margin"],
                  max_time: Optional[float] = None) -> Dict:
    """drive_figures of the path-mode controller driving `reward` through `scene` (barrier
    `margin` m beyond touching, cycle `budget` s or None: unlimited; for `max_time` s, default
    the scene's) plus its cycle times, last status and how often it recovered (detours,
    backing up, giving way)."""
    controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=budget,
                                   safety=dict(HALLWAY_SAFETY, barrier_margin=margin),
                                   grid=scene.grid)
    cycles: List[float] = []
    waits = WaitsForRobot(scene)

    def policy(state, t, seen):
        started = time.perf_counter()
        gave_way = controller.give_ways_
        command = controller.act(state, t, seen.angles, seen.ranges, seen.people, seen.velocities,
                                 seen.names)
        cycles.append(time.perf_counter() - started)
        waits.step(state, t, controller.give_ways_ > gave_way,
                   controller.status_.startswith(("waiting", "stopped")))
        return command
    figures = drive_figures(drive(scene, policy, max_time=max_time))
    figures["cycles"] = cycles
    figures["status"] = controller.status_
    figures["recoveries"] = {"detours": controller.detours_, "backing_up": controller.backups_,
                             "giving_way": controller.give_ways_}
    figures["giving_way"] = waits.figures()
    return figures


class WaitsForRobot:
    """The simulator's truth about giving way: whether someone near the robot was really
    waiting for it (`Walker.holding`) when the controller gave way, and the standoffs - someone
    near and in front (within 90 deg of its heading) waiting for the robot while it stood held
    up (not turning to its path), for WAIT_LONG s or more - in which it never did."""

    def __init__(self, scene: HallwayScene):
        self.scene = scene
        self.right = self.wrong = 0
        self.waits: Dict[int, List] = {}        # walker -> [since, gave way during it]
        self.missed = self.standoffs = 0
        self.last = 0.0

    def step(self, state, t: float, gave_way: bool, held: bool = True) -> None:
        """The robot at `state` at time `t`; `gave_way`: the controller began giving way;
        `held`: it is held up (waiting or stopped, not turning to its path)."""
        self.last = t
        waiting = {i for i, walker in enumerate(self.scene.people)
                   if walker.holding and walker.present(t)
                   and np.hypot(*(walker.position(t) - state[:2])) <= WAIT_NEAR}
        if gave_way:
            self.right, self.wrong = self.right + bool(waiting), self.wrong + (not waiting)
        if (abs(state[3]) >= STANDING or not held) and not gave_way:
            waiting = set()         # it drives on, or turns to its path: no standoff
        heading = np.array([math.cos(state[2]), math.sin(state[2])])
        waiting = {i for i in waiting
                   if np.dot(self.scene.people[i].position(t) - state[:2], heading) > 0.0}
        for i in waiting:
            self.waits.setdefault(i, [t, False])[1] |= gave_way
        for i in [i for i in self.waits if i not in waiting]:
            self._end(self.waits.pop(i), t)

    def _end(self, wait, t: float) -> None:
        if t - wait[0] >= WAIT_LONG:
            self.standoffs += 1
            self.missed += not wait[1]

    def figures(self) -> Dict[str, int]:
        """right / wrong: give-ways with / without someone near waiting for the robot;
        standoffs: of WAIT_LONG s or more (someone in front waiting while it was held up);
        missed: those it never gave way in (1 - missed / standoffs: its recall)."""
        for wait in list(self.waits.values()):
            self._end(wait, self.last)
        self.waits = {}
        return {"right": self.right, "wrong": self.wrong, "standoffs": self.standoffs,
                "missed": self.missed}


@dataclass
class Teaching:
    """What `teach` did: the scenes the person drove successfully with their figures, the
    windows, and (after learning) the reward, barrier margin, CPU seconds and the verdict."""

    demo_scenes: List[HallwayScene] = field(default_factory=list)
    person: List[Dict] = field(default_factory=list)
    windows: List = field(default_factory=list)
    step_windows: List = field(default_factory=list)
    speeds: List[float] = field(default_factory=list)
    tried: int = 0
    reward: object = None
    margin: float = HALLWAY_SAFETY["barrier_margin"]
    learn_cpu: float = 0.0
    learn_seconds: float = 0.0
    verdict: Optional[Dict] = None


def demonstrate(person: HallwayDriver, candidates: Sequence[HallwayScene], wanted: int,
                progress: Callable[[str], None] = lambda _: None) -> Teaching:
    """The person drives the candidate scenes in turn until `wanted` drives succeeded; only
    those are kept (windows of 40 steps every 20, and of 2 steps every step for cloning)."""
    taught = Teaching()
    for scene in candidates:
        if len(taught.demo_scenes) >= wanted:
            break
        taught.tried += 1
        result, tasks = hallway_demonstration(person, scene)
        figures = drive_figures(result)
        progress(f"scene {taught.tried}/{len(candidates)} {scene.name} ({len(scene.people)} "
                 f"people, {scene.length:.0f} m): " + (
                     f"demonstration {len(taught.demo_scenes) + 1}/{wanted}" if result.success
                     else "the person failed, not used"))
        if not result.success:
            continue
        taught.windows += hallway_windows(result.states, result.actions, tasks)
        taught.step_windows += hallway_windows(result.states, result.actions, tasks, length=2,
                                               stride=1)
        moving = result.states[:, 3]
        taught.speeds.append(float(np.median(moving[moving > 0.05])))
        taught.demo_scenes.append(scene)
        taught.person.append(figures)
    return taught


def learn(taught: Teaching, seed: int = 0) -> Teaching:
    """CIOC on the windows, the person's pace and room (fills reward, margin, learn_cpu)."""
    started, wall = time.process_time(), time.monotonic()
    reward, _ = fit_hallway_reward(taught.windows, seed)
    taught.reward = calibrate_pace(reward, float(np.median(taught.speeds)))
    taught.margin = room_margin([d["closest"] for d in taught.person])
    taught.learn_cpu = time.process_time() - started
    taught.learn_seconds = time.monotonic() - wall
    return taught


def check(taught: Teaching, progress: Callable[[str], None] = lambda _: None) -> Teaching:
    """The controller (no cycle budget) drives every demonstrated scene; the verdict."""
    drives = []
    for index, scene in enumerate(taught.demo_scenes):
        drives.append(drive_learner(scene, taught.reward, budget=None, margin=taught.margin))
        figures = drives[-1]
        outcome = ("reached the goal" if figures["success"] else
                   f"collided with {figures['collision']}" if figures["collision"] else
                   f"did not arrive in the scene's time ({figures['status']})")
        progress(f"acceptance {index + 1}/{len(taught.demo_scenes)}: {scene.name}: {outcome}")
    taught.verdict = hallway_acceptance(taught.person, drives)
    return taught


def teach(person: HallwayDriver, candidates: Sequence[HallwayScene], wanted: int, *,
          seed: int = 0, progress: Callable[[str], None] = lambda _: None) -> Teaching:
    """Demonstrations, learning and the acceptance check (module docstring); LfdError when no
    demonstration succeeded."""
    taught = demonstrate(person, candidates, wanted, progress)
    if not taught.demo_scenes:
        raise LfdError(f"no demonstration succeeded: the {person.family} person failed all "
                       f"{taught.tried} scenes tried")
    progress(f"learning from {len(taught.demo_scenes)} demonstrations "
             f"({len(taught.windows)} windows)")
    learn(taught, seed)
    progress(f"learned in {taught.learn_cpu:.1f} CPU-s; barrier margin {taught.margin:.2f} m")
    return check(taught, progress)


def family_person(family: str, seed: int = 0) -> HallwayDriver:
    """The person of `family` (seed 0: the building benchmark's)."""
    return HallwayDriver(family, seed=1000 + sorted(FAMILIES).index(family) + seed)


def reward_info(taught: Teaching, args: argparse.Namespace, accepted_anyway: bool) -> Dict:
    """The reward file's `info`: provenance, the verdict and the controller's settings."""
    verdict = dict(taught.verdict)
    if accepted_anyway:
        verdict["saved_anyway"] = "refused by the acceptance check, saved with --accept-anyway"
    return {"source": "lfd_controller.sim.teach_hallway", "family": args.family,
            "floor": args.floor, "layout": args.layout, "seed": args.seed, "length_m": list(args.length),
            "demonstrations": len(taught.demo_scenes), "scenes_tried": taught.tried,
            "scenes": [s.name for s in taught.demo_scenes], "windows": len(taught.windows),
            "learning_seconds": round(taught.learn_seconds, 2),
            "learning_cpu_seconds": round(taught.learn_cpu, 2),
            "acceptance": verdict, "controller": {"barrier_margin": round(taught.margin, 4)}}


def parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    parse = argparse.ArgumentParser(
        prog="python -m lfd_controller.sim.teach_hallway",
        description="Learn a path-mode reward from a simulated person's drives on a floor.")
    parse.add_argument("--family", required=True, choices=sorted(FAMILIES),
                       help="the simulated person's family (lfd_controller.sim.families)")
    parse.add_argument("--floor", default="generated:0",
                       help="generated:SEED (robot_sim.building) or a map_server .yaml file")
    parse.add_argument("--layout", choices=LAYOUTS, default="hall",
                       help="a generated floor: its main and back halls, or with a second way "
                            "round (loop)")
    parse.add_argument("--demos", type=int, default=3, help="successful demonstrations wanted")
    parse.add_argument("--out", required=True, help="the reward file to write (YAML)")
    parse.add_argument("--seed", type=int, default=0,
                       help="the person's and the scenes' seed (0: the building benchmark's)")
    parse.add_argument("--length", type=float, nargs=2, default=list(LENGTH),
                       metavar=("MIN", "MAX"), help="start to goal along the halls (m)")
    parse.add_argument("--accept-anyway", action="store_true",
                       help="save a reward the acceptance check refuses (stated in the file)")
    return parse


def run(args: argparse.Namespace, progress: Callable[[str], None]) -> str:
    """Teach and save as the command line says; returns the summary line (LfdError: refused)."""
    if args.demos < 1:
        raise LfdError(f"--demos must be at least 1, got {args.demos}")
    grid = floor_grid(args.floor, args.layout)
    first = FIRST_SCENE + 1000 * args.seed
    candidates = scenes(grid, "teach", range(first, first + TRIES * args.demos),
                        length=tuple(args.length))
    taught = teach(family_person(args.family, args.seed), candidates, args.demos,
                   seed=args.seed, progress=progress)
    accepted = taught.verdict["accepted"]
    if not accepted and not args.accept_anyway:
        raise LfdError("the learned reward was NOT saved: its controller fails where the person "
                       "succeeded (" + "; ".join(taught.verdict["failures"]) + "); "
                       "--accept-anyway saves it regardless")
    path = save_reward(taught.reward, args.out,
                       **reward_info(taught, args, accepted_anyway=not accepted))
    state = "accepted" if accepted else "REFUSED, saved with --accept-anyway"
    return (f"{path}: a {args.family} reward from {len(taught.demo_scenes)} demonstrations "
            f"({len(taught.windows)} windows) on {args.floor}, {state}, barrier margin "
            f"{taught.margin:.2f} m")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The command line; 0 saved, 1 refused or no successful demonstration (one ERROR line)."""
    args = parser().parse_args(argv)

    def progress(line: str) -> None:
        print(f"teach_hallway: {line}", file=sys.stderr, flush=True)
    try:
        with threadpool_limits(1):      # small matrices: BLAS threads only contend
            print(run(args, progress))
    except LfdError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
