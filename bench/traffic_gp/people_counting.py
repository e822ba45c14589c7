#!/usr/bin/env python3
"""The people counter with real nodes against the simulator's truth.

Starts a roscore, robot_sim's simulated robot (`sim.launch crowd:=true`: the generated building,
the robot patrolling its main hall, a 270-degree 10 m laser that sees walls and people, tf
map -> odom -> base_link -> laser, a people tracker with 10% misses and 10% false tracks) and
traffic_gp's `people_counter`, records N watches and prints (`traffic_gp.sim.counting_check`):
  count ratio   people counted in the reported cells / the different true people in them;
  recall        cells whose centre a scan truly saw, reported seen (within the counter's range);
  hidden        reported cells truly hidden (behind walls or people, out of view) in every scan;
and the counter's CPU seconds per wall second. Targets: ratio within 0.9-1.1, recall >= 0.95,
hidden 0. Writes artifacts/bench/people_counting.json.

  python bench/traffic_gp/people_counting.py [--watches 30] [--watch 10] [--peak-density 1.0]
      [--crowd-hour 62]
"""
import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

from robot_common.cells import CellGrid  # noqa: E402
from robot_common.ros_node import shut_down_rospy  # noqa: E402
from robot_sim import generate_building  # noqa: E402
from ros_harness import LaunchSet, RosCore, wait_until  # noqa: E402
from traffic_gp.sim.counting_check import check_counts  # noqa: E402


def process_cpu(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(args) -> dict:
    import rospy

    with RosCore(log_dir=tc.OUT / "people_counting_logs") as core:
        os.environ.update(core.env())
        rospy.init_node("people_counting_bench", anonymous=True, disable_signals=True)
        from traffic_gp.sim.ros_counting_check import CountingRecorder

        recorder = CountingRecorder()
        launches = LaunchSet(core, tc.OUT / "people_counting_logs")
        try:
            launches("robot_sim", "sim.launch", crowd=True, crowd_hour=args.crowd_hour,
                     peak_density=args.peak_density)
            counter = launches("traffic_gp", "people_counter.launch", watch=args.watch,
                               robot_id="bench_robot")
            counter.wait_for_nodes(["/people_counter"], timeout=120)
            pid = counter.node_pid("/people_counter")
            wait_until(lambda: len(recorder.counts) >= 1, 300, what="a first watch")
            cpu0, wall0 = process_cpu(pid), time.monotonic()
            wait_until(lambda: len(recorder.counts) >= args.watches + 1,
                       args.watches * args.watch * 5 + 300, what=f"{args.watches} watches",
                       interval=1.0)
            cpu_per_s = (process_cpu(pid) - cpu0) / (time.monotonic() - wall0)
        finally:
            recorder.stop()
            launches.stop_all()
            shut_down_rospy("bench finished")
    cells = CellGrid.from_map(generate_building(0).grid, 0.5)
    result = check_counts(cells, recorder.watches(cells), recorder.true_scans(), max_range=8.0)
    return {"watches": result.watches, "watch_s": args.watch, "counted": result.counted,
            "truth": result.truth, "count_ratio": result.count_ratio, "recall": result.recall,
            "hidden_reported": result.hidden_reported, "reported": result.reported,
            "counter_cpu_per_s": cpu_per_s, "peak_density": args.peak_density,
            "crowd_hour": args.crowd_hour, "line": result.line(), "machine": tc.machine_note()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--watches", type=int, default=30)
    parser.add_argument("--watch", type=float, default=10.0)
    parser.add_argument("--peak-density", type=float, default=1.0)
    parser.add_argument("--crowd-hour", type=float, default=62.0)
    args = parser.parse_args()
    figures = run(args)
    print(figures["line"])
    print("| watches | counted / true people | ratio | seen-cell recall | hidden cells reported "
          "| counter CPU s per s |")
    print("|---|---|---|---|---|---|")
    print(f"| {figures['watches']} x {args.watch:g} s | {figures['counted']} / {figures['truth']} "
          f"| {figures['count_ratio']:.3f} | {figures['recall']:.3f} | "
          f"{figures['hidden_reported']} of {figures['reported']} | "
          f"{figures['counter_cpu_per_s']:.2f} |")
    tc.write_json("people_counting", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
