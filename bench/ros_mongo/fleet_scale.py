#!/usr/bin/env python3
"""Fleet at scale: >= 10 robots through launch/fleet.launch (its default: straight to central with
the spool) into a real 3-node Apache CouchDB cluster, one node killed and restarted, then central
cut off.

    scripts/in_env.sh python bench/ros_mongo/fleet_scale.py            # 10 robots, about 4 min
    scripts/in_env.sh python bench/ros_mongo/fleet_scale.py --quick    # 3 robots, short phases

The cluster (../shared/couchdb, ros_harness.CouchDBCluster: n = 3, q = 2) runs in a temporary
folder on free ports; an admin creates the database `fleet` with a member account, which every
robot's recorder uses (a credentials file). Robot i (its own roscore, as on real robots) writes
through node i mod 3. Each robot publishes a lighter load than the standard one (fleet_bench's
publisher: 20 Hz nav_msgs/Odometry, 5 Hz 1081-beam LaserScan, a 640x480 rgb8 Image every 5 s; set
with --rates). Phases: `--steady` s, then node 3 is killed (SIGKILL) for `--down` s and started
again; `--steady` s later the whole cluster is stopped (central cut off) for `--cut` s and started
again; publishing goes on for `--tail` s more.

Figures: published vs stored centrally by content (robot, topic, header.seq; read as the admin
after the run): lost and duplicates (targets: 0 and 0); central CPU (beam.smp of the three nodes,
every pid they had, user + system from /proc) per message and per MB stored, from the first
message until central is idle after the drain; arrival lag = time the message is in central's
`_changes` (fleet_bench.CentralWatch on node 1) minus its receive time on the robot, p50/p99 over
the steady phase before the kill and over the whole run; robot CPU: each robot's roslaunch tree
(the recorder) against `rosbag record` of robot 1's topics run beside it in the same run (the
peer, as a ratio). Written to artifacts/bench/fleet_scale.json.
"""
import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
import fleet_bench  # noqa: E402
from fleet_bench import CentralWatch, Robot, _percentiles, _progress  # noqa: E402
from ros_mongo_bench_lib import CpuWatch  # noqa: E402

from ros_harness import CouchDBCluster, ManagedProcess, wait_until  # noqa: E402
from ros_harness.apache_couchdb import missing_reason, shared_couchdb_dir  # noqa: E402

RATES = {"/odom": 20.0, "/scan": 5.0, "/camera/rgb/image_raw": 0.2}
KILLED = 2  # node 3 (0-based index)


class ScaleRobot(Robot):
    """fleet_bench's robot, publishing this benchmark's rates, its recorder writing straight to
    one cluster node with the member's credentials from a file."""

    def start_member(self, central_db_url: str, credentials: Path) -> None:
        self.nodes = self.launches(str(ROOT / "launch" / "fleet.launch"), central_url=central_db_url,
                                   robot_id=self.robot_id, central_credentials_file=str(credentials),
                                   topics=fleet_bench._yaml_list(RATES), spool_path=str(self.work / "spool"))

    def publish(self, duration, topics=()):
        rates = [f"{t}={r}" for t, r in RATES.items()]
        self.publisher = ManagedProcess([sys.executable, __file__, "--publish", duration, "--rates", *rates],
                                        name=f"publisher {self.robot_id}",
                                        log_path=self.work / f"publisher_{time.time_ns()}.log",
                                        env=self.core.env()).start()


class CentralCpu:
    """CPU seconds of every beam.smp the cluster ran (a killed node's until it died), sampled."""

    def __init__(self, cluster: CouchDBCluster):
        self.cluster, self.watch, self.names = cluster, CpuWatch(period=0.5), []
        self.track()

    def track(self) -> None:
        """Watch the nodes' current pids (call after a node started again)."""
        for pid in self.cluster.pids():
            name = f"beam {pid}"
            if name not in self.names:
                self.watch.add(name, pid)
                self.names.append(name)

    def mark(self, label: str) -> None:
        self.watch.mark(label)

    def since(self, label: str) -> float:
        self.watch.sample()
        return sum(self.watch.cpu(name, label) for name in self.names if label in self.watch.marks)


def central_contents(admin_db_url: str):
    """(robot_id, topic, header.seq) of every message central holds, and stored bytes, read as
    the admin through the product's own reader (documents and chunks alike)."""
    from ros_mongo import open_store
    from ros_mongo.query import Query

    contents, size = [], 0
    with open_store(admin_db_url, warn_password=False) as store:
        for message in store.find(Query.build()):
            header = (message.fields or {}).get("header") or {}
            contents.append((message.robot_id, message.topic, header.get("seq")))
            size += message.size
    return contents, size


def run(args, work: Path, scripts: Path) -> dict:
    cluster = CouchDBCluster(scripts, Path(tempfile.mkdtemp(prefix="fleet_scale_cluster_"))).start()
    robots, bag = [], None
    try:
        cluster.create_database("fleet")
        credentials = work / "central.credentials"
        credentials.write_text(":".join(cluster.member) + "\n")
        credentials.chmod(0o600)
        admin_url = cluster.admin_database_url("fleet")
        cpu = CentralCpu(cluster)
        robots = [ScaleRobot(i, work) for i in range(1, args.robots + 1)]
        for robot in robots:
            robot.start_member(cluster.plain_url((robot_index(robot)) % 3) + "/fleet", credentials)
        for robot in robots:
            robot.nodes.wait_for_subscribers(list(RATES), timeout=300)
        bag = ManagedProcess(["rosbag", "record", "--quiet", "-O", str(work / "peer.bag"), *RATES],
                             name="rosbag record", log_path=work / "rosbag.log",
                             env=robots[0].core.env()).start()
        robot_cpu = CpuWatch(period=0.5)
        for robot in robots:
            robot_cpu.add(robot.robot_id, robot.nodes.process.pid)
        robot_cpu.add("rosbag record", bag.pid)
        watch = CentralWatch(admin_url)
        total = 2 * args.steady + args.cut + args.tail
        for robot in robots:
            robot.publish(total)
        wait_until(lambda: watch.count() > 0, 300, what="the first message central")
        t0, first = time.time(), watch.count()
        cpu.mark("start")
        robot_cpu.mark("start")
        steady = {}

        def snapshot():  # the steady phase's figures, taken just before the kill
            steady.update(central=cpu.since("start"), messages=watch.count() - first,
                          recorders=[robot_cpu.cpu(r.robot_id, "start") for r in robots],
                          rosbag=robot_cpu.cpu("rosbag record", "start"))
        events = phases(args, cluster, cpu, watch, t0, snapshot)
        wait_until(lambda: not any(r.publisher.alive for r in robots), total + 600, what="publishers done")
        robot_cpu.mark("published")
        published = {r.robot_id: json.loads(next(line for line in r.publisher.log_path.read_text()
                                                  .splitlines() if line.startswith("{")))["published"]
                     for r in robots}
        expected = sum(sum(p.values()) for p in published.values())
        fleet_bench._drain(watch, expected, "draining")
        drained = time.time()
        wait_idle(cpu)
        central_seconds = cpu.since("start")
        contents, size = central_contents(admin_url)
        want = {(r, t, i) for r, counts in published.items() for t, n in counts.items() for i in range(n)}
        arrivals = list(watch.arrivals.values())
        steady_lags = [a - r for a, r in arrivals if t0 + 5 <= r < events["kill"] - 5]
        steady_recorder = sum(steady["recorders"]) / len(robots)
        recorders = [robot_cpu.cpu(r.robot_id, "start") for r in robots]
        rosbag = robot_cpu.cpu("rosbag record", "start")
        robot_cpu.close()
        return {
            "robots": args.robots, "rates_hz": RATES, "phases_s": vars_of(args),
            "events_s": {k: v - t0 for k, v in events.items()}, "drained_s": drained - t0,
            "published": expected, "central": len(contents), "lost": len(want - set(contents)),
            "duplicates": len(contents) - len(set(contents)), "unexpected": len(set(contents) - want),
            "central_cpu_s": central_seconds, "central_mb": size / 2 ** 20,
            "central_ms_per_message": 1000 * central_seconds / max(1, len(contents)),
            "central_ms_per_mb": 1000 * central_seconds / max(1e-9, size / 2 ** 20),
            "steady_central_cpu_s": steady["central"], "steady_messages": steady["messages"],
            "steady_central_ms_per_message": 1000 * steady["central"] / max(1, steady["messages"]),
            "steady_recorder_over_rosbag": steady_recorder / steady["rosbag"] if steady["rosbag"] else None,
            "lag_steady_s": _percentiles(steady_lags),
            "lag_all_s": _percentiles([a - r for a, r in arrivals]),
            "recorder_cpu_s_per_robot": sum(recorders) / len(recorders),
            "recorder_cpu_s_max": max(recorders), "rosbag_record_cpu_s": rosbag,
            "recorder_over_rosbag": (sum(recorders) / len(recorders)) / rosbag if rosbag else None,
        }
    finally:
        if bag is not None:
            bag.stop()
        for robot in robots:
            robot.close()
        cluster.stop()
        shutil.rmtree(cluster.dir, ignore_errors=True)


def robot_index(robot) -> int:
    return int(robot.robot_id[len("robot"):]) - 1


def vars_of(args) -> dict:
    return {"steady": args.steady, "node_down": args.down, "cut": args.cut, "tail": args.tail}


def phases(args, cluster: CouchDBCluster, cpu: CentralCpu, watch, t0: float, snapshot) -> dict:
    """Node 3 killed and restarted, then the whole cluster stopped and started; returns when."""
    events = {}
    _sleep_until(t0 + args.steady, watch, "steady")
    snapshot()
    events["kill"] = time.time()
    pid = cluster.kill_node(KILLED)
    print(f"  {time.strftime('%H:%M:%S')} node 3 (pid {pid}) killed for {args.down:.0f} s", flush=True)
    _sleep_until(events["kill"] + args.down, watch, "node 3 down")
    cluster.start()
    cpu.track()
    events["node_back"] = time.time()
    print(f"  {time.strftime('%H:%M:%S')} node 3 back", flush=True)
    _sleep_until(t0 + 2 * args.steady, watch, "steady")
    cpu.watch.sample()
    cluster.stop()
    events["cut"] = time.time()
    print(f"  {time.strftime('%H:%M:%S')} central cut off (all nodes stopped) for {args.cut:.0f} s",
          flush=True)
    _sleep_until(events["cut"] + args.cut, watch, "cut off")
    cluster.start()
    cpu.track()
    events["central_back"] = time.time()
    print(f"  {time.strftime('%H:%M:%S')} central back", flush=True)
    return events


def _sleep_until(when: float, watch, label: str) -> None:
    """The phases are lengths of time: sleep until `when`, showing progress every 5 s."""
    while time.time() < when:
        time.sleep(min(5.0, max(0.0, when - time.time())))
        _progress(label, watch)


def wait_idle(cpu: CentralCpu, rate: float = 0.2, timeout: float = 300.0) -> None:
    """Until the cluster uses under `rate` cores over 5 s (shard syncing after the last write)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        before = cpu.since("start")
        time.sleep(5.0)
        if cpu.since("start") - before < 5.0 * rate:
            return


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publish", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--rates", nargs="*", default=[], metavar="TOPIC=HZ",
                        help="publishing rates per topic (default " +
                             ", ".join(f"{t}={r}" for t, r in RATES.items()) + ")")
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--steady", type=float, default=30.0, help="seconds before the kill and the cut")
    parser.add_argument("--down", type=float, default=15.0, help="seconds node 3 is down")
    parser.add_argument("--cut", type=float, default=15.0, help="seconds central is cut off")
    parser.add_argument("--tail", type=float, default=15.0, help="seconds published after the cut")
    parser.add_argument("--quick", action="store_true", help="3 robots, 10 s phases")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "bench")
    args, _ = parser.parse_known_args()
    for item in args.rates:
        topic, _, rate = item.partition("=")
        RATES[topic] = float(rate)
    if args.publish is not None:
        fleet_bench.RATES.update(RATES)
        return fleet_bench.publish(args.publish, list(RATES))
    if args.quick:
        args.robots, args.steady, args.down, args.cut, args.tail = 3, 10.0, 8.0, 8.0, 5.0
    scripts = shared_couchdb_dir(ROOT)
    reason = missing_reason(scripts)
    if reason:
        print(f"fleet_scale: {reason}", file=sys.stderr)
        return 2
    args.output.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="fleet_scale_", dir=args.output))
    print(f"{args.robots} robots -> a 3-node CouchDB cluster; {args.steady:.0f} s steady, node 3 down "
          f"{args.down:.0f} s, central cut off {args.cut:.0f} s, {args.tail:.0f} s after", flush=True)
    result = run(args, work, scripts)
    (args.output / "fleet_scale.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))
    print(f"lost {result['lost']}, duplicates {result['duplicates']} of {result['published']}; "
          f"central CPU per message {result['steady_central_ms_per_message']:.2f} ms steady, "
          f"{result['central_ms_per_message']:.2f} ms over the whole run with its restarts "
          f"({result['central_ms_per_mb']:.0f} ms per MB); arrival lag p50/p99 steady "
          f"{_fmt(result['lag_steady_s'])}, whole run {_fmt(result['lag_all_s'])}; recorder CPU "
          f"{result['steady_recorder_over_rosbag']:.2f}x rosbag record steady, "
          f"{result['recorder_over_rosbag']:.2f}x over the whole run", flush=True)
    ok = result["lost"] == 0 and result["duplicates"] == 0 and result["unexpected"] == 0
    print(f"targets (0 lost, 0 duplicates): {'met' if ok else 'NOT met'}", flush=True)
    return 0


def _fmt(p) -> str:
    return "-" if p["p50"] is None else f"{p['p50']:.2f}/{p['p99']:.2f} s"


if __name__ == "__main__":
    sys.exit(main())
