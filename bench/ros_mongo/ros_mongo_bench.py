#!/usr/bin/env python3
"""ros_mongo benchmark, everything in one run on this machine:

    scripts/in_env.sh python bench/ros_mongo/ros_mongo_bench.py          # about 30 min
    scripts/in_env.sh python bench/ros_mongo/ros_mongo_bench.py --quick  # a 5 min smoke run

The standard load (bench_publisher.py): 1 kHz nav_msgs/Odometry, 30 Hz 640x480 rgb8 Image, 40 Hz
1081-beam LaserScan, `--duration` s (20).
1. fault runs (launch/fleet.launch's default recorder, ros_harness.fault_proxy between it and
   central): `--fault-seconds` (30) of 401 then of 500 timeout, default spool: lost (target 0);
   then a full spool: 2 x `--fault-seconds` of central unreachable into a `--spool-mb` (200)
   spool: lost per topic against dropped per topic on /diagnostics (target: images only, each
   loss counted).
2. record (record_configs.py): each configuration beside `rosbag record` of the same topics at the
   same time: recorder to a database on another machine (CouchDB, MongoDB), the fleet default,
   the fleet with a local store + replication. Stored per s (x rosbag), drops, robot-side CPU
   seconds from /proc (x rosbag record's `record` process; target fleet default <= 1.3x), peak RSS.
3. import: the recorded bag into each database against the same server's raw bulk-insert rate of
   the same payloads (target >= 0.9).
4. replay: ros_mongo_retriever against rosbag play of the same data, `--replay-repeats` (6)
   alternating pairs: gap error |received gap - recorded gap| p50/p99 pooled, per run, and the
   spread of the pairs' p99 ratios (target: pooled p99 <= 1.0x rosbag play's).

`--only-fault`, `--only-record`, `--bag FILE --only-import`, `--bag FILE --only-replay` run one stage
(`--keep` keeps the bags). Figures are printed and written to artifacts/bench/ros_mongo.json, the
plot to artifacts/bench/ros_mongo_bench.png.
"""
import argparse
import json
import os
import shutil
import sys
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

from ros_mongo_bench_lib import BACKENDS, plot_results, start_servers  # noqa: E402 - after the path set-up

from ros_harness import RosCore  # noqa: E402


def say(text=""):
    print(text, flush=True)


def report(results):
    say("\n== ros_mongo benchmark ==")
    for name, fault in results.get("fault", {}).items():
        seconds = fault["fault_seconds"]
        what = (f"{2 * seconds:.0f} s of central unreachable into a {fault['spool_max_mb']} MB spool"
                if fault["spool_max_mb"] else f"{seconds:.0f} s of 401 then {seconds:.0f} s of 500 timeout")
        say(f"{name} ({what}): published {sum(fault['published'].values())}, lost {fault['lost_total']} "
            f"{fault['lost']}, dropped as counted on /diagnostics {fault['dropped_counted']} (every loss "
            f"counted: {fault['every_loss_counted']}); spool drained "
            f"{fault['drain_seconds_after_recovery']:.1f} s after recovery; recorder peak RSS "
            f"{fault['peak_rss_mb']:.0f} MB")
    say("record (robot-side CPU seconds from the start of publishing, x rosbag record's record process "
        "in the same run):")
    say(f"  {'configuration':58s} {'stored/s x':>10s} {'drops':>6s} {'robot CPU s':>11s} {'x rosbag':>8s} "
        f"{'rosbag s':>8s}  peak RSS MB")
    for name, rec in results.get("record", {}).items():
        cpu = rec["cpu"]
        rss = ", ".join(f"{k} {v:.0f}" for k, v in cpu["peak_rss_mb"].items())
        say(f"  {rec['title']:58s} {rec['ratio_stored_per_s']:10.3f} {rec['recorder']['drops_total']:6d} "
            f"{cpu['seconds']['robot_side']:11.2f} {cpu['x_rosbag_record']['robot_side']:8.2f} "
            f"{cpu['seconds']['rosbag_record']:8.2f}  {rss}")
        parts = ", ".join(f"{k} {v:.2f}" for k, v in cpu["seconds"].items()
                          if k not in ("robot_side", "rosbag_record"))
        say(f"    {name}: {rec['stored_while_publishing']} stored while publishing, all "
            f"{rec['drain_seconds_after_publishing']:.1f} s later (sustained {rec['ratio_sustained']:.2f} x "
            f"rosbag); CPU s: {parts}; rosbag drops {rec['rosbag']['drops_total']}")
    for backend, imp in results.get("import", {}).items():
        if "raw_msgs_per_s" not in imp:
            say(f"import ({backend}, {imp['messages']} msgs): {imp['import_msgs_per_s']:.0f} msgs/s "
                f"(for the replay)")
            continue
        say(f"import ({backend}, {imp['messages']} msgs, {imp['megabytes']:.0f} MB): "
            f"{imp['import_msgs_per_s']:.0f} msgs/s; raw bulk {imp['raw_msgs_per_s']:.0f} msgs/s (before / "
            f"after {imp['raw_before_msgs_per_s']:.0f} / {imp['raw_after_msgs_per_s']:.0f}): ratio "
            f"{imp['ratio_msgs']:.2f} (msgs) {imp['ratio_mb']:.2f} (MB)")
    replay = results.get("replay", {})
    for who in ("rosbag_play", "ros_mongo_retriever"):
        if who not in replay:
            continue
        rep = replay[who]
        per_run = ", ".join(f"{v:.2f}" for v in rep["p99_ms_per_run"])
        say(f"replay {who:20s} gap error p50 {rep['all']['p50_ms']:.3f} ms, p99 "
            f"{rep['all']['p99_ms']:.3f} ms (pooled, {len(rep['p99_ms_per_run'])} runs; per run {per_run}), "
            f"received {rep['all']['received']}/{rep['all']['expected']}")
        for topic, value in rep.items():
            if topic.startswith("/"):
                say(f"    {topic:24s} p50 {value['p50_ms']:.3f} ms, p99 {value['p99_ms']:.3f} ms")
    if "p99_ratio" in replay:
        ratio = replay["p99_ratio"]
        say(f"replay p99 retriever / rosbag play: pooled {ratio['pooled']:.2f}; pairs median "
            f"{ratio['median_pair']:.2f}, range {ratio['min_pair']:.2f}-{ratio['max_pair']:.2f}, "
            f"{ratio['pairs_at_most_1']} of {len(ratio['pairs'])} pairs <= 1.0")


def _arguments(argv):
    from record_configs import CONFIGS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run: 5 s of publishing, short faults, "
                        "CouchDB only, 2 replay pairs")
    parser.add_argument("--duration", type=float, help="seconds of publishing (default 20, quick 5)")
    parser.add_argument("--configs", nargs="*", choices=CONFIGS, help="record configurations (default all)")
    parser.add_argument("--backends", nargs="*", choices=BACKENDS, help="import backends (default both)")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "bench")
    parser.add_argument("--keep", action="store_true", help="keep the work folder (bags, databases)")
    parser.add_argument("--bag", type=Path, help="skip recording: import and replay this bag (kept by an "
                        "earlier run with --keep)")
    parser.add_argument("--replay-repeats", type=int, help="alternating replay pairs (default 6, quick 2)")
    parser.add_argument("--retriever-param", nargs="*", default=[], metavar="KEY=YAML",
                        help="extra ros_mongo_retriever parameters for the replay stage")
    parser.add_argument("--fault-seconds", type=float, help="length of each fault (default 30, quick 5)")
    parser.add_argument("--spool-mb", type=float, default=200.0, help="the full-spool run's ~spool_max_mb")
    for stage in ("fault", "record", "import", "replay"):
        parser.add_argument(f"--only-{stage}", action="store_true", help=f"run only the {stage} stage")
    parser.add_argument("--publish", type=float, help=argparse.SUPPRESS)  # the load, as its own process
    parser.add_argument("--wait-subscribers", type=int, default=1, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if (args.only_import or args.only_replay) and args.bag is None:
        parser.error("--only-import and --only-replay need --bag (a bag kept by an earlier run with --keep, "
                     "e.g. artifacts/bench/ros_mongo_work/record_remote_couchdb.bag)")
    args.duration = args.duration or (5.0 if args.quick else 20.0)
    args.fault_seconds = args.fault_seconds or (5.0 if args.quick else 30.0)
    args.replay_repeats = args.replay_repeats or (2 if args.quick else 6)
    quick_configs = [c for c in CONFIGS if c != "remote_mongodb"]
    args.configs = args.configs or (quick_configs if args.quick else list(CONFIGS))
    args.backends = args.backends or (["couchdb"] if args.quick else list(BACKENDS))
    return args


def main(argv=None):
    args = _arguments(argv)
    if args.publish is not None:
        from bench_publisher import publish

        return publish(args.publish, args.wait_subscribers)
    from import_replay import bench_import, bench_replay
    from record_configs import fault_run, record_config

    args.output.mkdir(parents=True, exist_ok=True)
    work = args.output / ("ros_mongo_work" if args.bag is None else "ros_mongo_work_replay")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    core = RosCore(log_dir=work / "logs").start()
    os.environ.update(core.env())
    needed = set(args.backends) | {"couchdb"} | {c.split("_", 1)[1] for c in args.configs
                                                 if c.startswith("remote_")}
    servers = start_servers(work, [b for b in BACKENDS if b in needed])
    import rospy

    rospy.init_node("ros_mongo_bench", anonymous=True, disable_signals=True)
    load = os.getloadavg()
    results = {"duration": args.duration, "load_before": load, "cpus": os.cpu_count(), "record": {}}
    only = [s for s in ("fault", "record", "import", "replay") if getattr(args, f"only_{s}")]
    stages = only or (["import", "replay"] if args.bag else ["fault", "record", "import", "replay"])
    try:
        if "fault" in stages:
            say(f"fault runs: {args.fault_seconds:.0f} s of 401 then of 500 timeout; then central "
                f"unreachable for {2 * args.fault_seconds:.0f} s into a {args.spool_mb:.0f} MB spool ...")
            results["fault"] = {
                "fault": fault_run(core, servers["couchdb"], work, args.fault_seconds),
                "full_spool": fault_run(core, servers["couchdb"], work, args.fault_seconds,
                                        spool_max_mb=args.spool_mb)}
        if "record" in stages:
            for name in args.configs:
                say(f"record: {name}, {args.duration:.0f} s of publishing ...")
                results["record"][name] = record_config(core, servers, work, args.duration, name)
        if "import" in stages or "replay" in stages:
            bag = args.bag or Path(next(iter(results["record"].values()))["bag"])
            say("import ...")
            targets = args.backends[:1] if stages == ["replay"] else args.backends
            results["import"] = bench_import(bag, {b: servers[b].database_url("bench") for b in targets},
                                             raw_rate="import" in stages)
        if "replay" in stages:
            say("replay ...")
            extra = {k: yaml.safe_load(v) for k, v in (p.split("=", 1) for p in args.retriever_param)}
            results["replay"] = bench_replay(core, bag, servers[args.backends[0]].database_url("bench"), work,
                                             extra, args.replay_repeats)
    finally:
        rospy.signal_shutdown("bench finished")
        for server in servers.values():
            server.stop()
        core.stop()
        results["load_after"] = os.getloadavg()
    report(results)
    name = "ros_mongo.json" if not only else f"ros_mongo_{only[0]}.json"
    (args.output / name).write_text(json.dumps(results, indent=1, default=str))
    if not only:
        plot_results(results, args.output)
    say(f"\nload average before {load[0]:.1f}, after {results['load_after'][0]:.1f} ({os.cpu_count()} CPUs); "
        f"figures in {args.output / name}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
