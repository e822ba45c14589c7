#!/usr/bin/env python3
"""reward_controller's cycle time in path mode with 8 people (what the node does each cycle:
scan points, local waypoint, planning with the 0.1 s budget of its 10 Hz rate).

A reward is learned from demonstrations of one family on the training floor (the generated
building, seed 0; `--family`, default tangent: a development family), then the controller
drives `--scenes` scenes with 8 people and one piece of clutter on each test floor (the real
Levine 4th and 6th floors in ../shared/data/maps, or a larger generated building when that
folder is absent). Prints each cycle's wall-clock time as p50 / p99 / max over all cycles, the
share over the budget, and the load average before and after (the machine is shared: the
figure is only as good as the load it was measured under).

Run: `OMP_NUM_THREADS=1 python bench/lfd_controller/lfd_cycle.py --scenes 2` (about 1 CPU-min:
20 s learning, 4 drives).
"""
import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from lfd_controller.hallway import (  # noqa: E402
    HallwayController,
    calibrate_pace,
    fit_hallway_reward,
    hallway_windows,
)
from lfd_controller.sim.hallway_people import HallwayDriver, hallway_demonstration  # noqa: E402
from robot_common.maps import load_map  # noqa: E402
from robot_common.unicycle import Unicycle  # noqa: E402
from robot_sim.building import generate_building  # noqa: E402
from robot_sim.hallway import drive, make_scene  # noqa: E402

MAPS = Path(__file__).resolve().parents[3] / "shared" / "data" / "maps"
LENGTH = (10.0, 30.0)


def learned_reward(family: str, demos: int):
    grid = generate_building(0).grid
    person = HallwayDriver(family, seed=4242)
    windows, speeds = [], []
    for seed in range(100, 100 + 4 * demos):
        if len(speeds) >= demos:
            break
        result, tasks = hallway_demonstration(person, make_scene(grid, seed, people=2 + seed % 7,
                                                                 length=LENGTH))
        if result.success:
            windows += hallway_windows(result.states, result.actions, tasks)
            moving = result.states[:, 3]
            speeds.append(float(np.median(moving[moving > 0.05])))
    reward, _ = fit_hallway_reward(windows)
    return calibrate_pace(reward, float(np.median(speeds)))


def test_floors():
    if MAPS.is_dir():
        return [(name, load_map(MAPS / f"{name}.yaml")) for name in ("levine_4th_good", "levine_6th")]
    return [("generated_seed7", generate_building(7, rooms_per_side=7).grid)]


def main(args) -> int:
    print(f"load average before: {os.getloadavg()}", flush=True)
    started = time.process_time()
    reward = learned_reward(args.family, args.demos)
    print(f"reward learned from {args.demos} {args.family} drives "
          f"({time.process_time() - started:.0f} CPU-s)", flush=True)
    cycles, outcomes = [], []
    for floor, grid in test_floors():
        for seed in range(3000, 3000 + args.scenes):
            scene = make_scene(grid, seed, people=8, clutter=1, length=LENGTH, name=f"{floor}/{seed}")
            controller = HallwayController(reward, scene.path, Unicycle(0.1), budget=0.1)

            def policy(state, t, seen, controller=controller):
                begun = time.perf_counter()
                command = controller.act(state, t, seen.angles, seen.ranges, seen.people,
                                         seen.velocities)
                cycles.append(time.perf_counter() - begun)
                return command
            result = drive(scene, policy)
            outcomes.append(result.success)
            print(f"{scene.name}: {len(result.actions)} cycles, success {result.success}, "
                  f"{controller.status_}", flush=True)
    times = np.array(cycles) * 1000.0
    print(f"load average after: {os.getloadavg()}")
    print(f"cycle time with 8 people, 0.1 s budget: {len(times)} cycles over {len(outcomes)} "
          f"drives, p50 {np.percentile(times, 50):.1f} ms, p99 {np.percentile(times, 99):.1f} ms, "
          f"max {times.max():.1f} ms, over 100 ms: {np.mean(times > 100.0):.2%}")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--family", default="tangent")
    parser.add_argument("--demos", type=int, default=3)
    parser.add_argument("--scenes", type=int, default=3, help="scenes per test floor")
    sys.exit(main(parser.parse_args()))
