#!/usr/bin/env python3
"""Fleet benchmark: three robots, each through launch/fleet.launch, to one central CouchDB-API server.

Each robot (its own roscore; with a local pouchdb-server in the replicated run) gets 100 Hz
nav_msgs/Odometry, 10 Hz 1081-beam sensor_msgs/LaserScan and 5 Hz 640x480 rgb8 sensor_msgs/Image
(921 KB: an attachment) from a publisher of this script (`--publish`, a real ROS node). Run 1
(replicated): `--duration` s of steady state, then the central server is stopped for `--partition`
s while the robots keep recording, then restarted; `--tail` s more (fleet.launch local_db:=true).
Run 2 (direct: fleet.launch's default): the same robots' recorders write straight to the central
server for `--duration` s.

Figures: messages lost (published - central), central throughput (messages/s and MB/s stored
centrally), lag = time a message is stored centrally (the central `update_seq` has reached its
sequence: `CentralWatch`) minus its receive time on the robot (same machine clock), p50/p99 in
steady state (messages received after the first 5 s of run 1 and more than CUT_GUARD = 10 s
before the partition), whether replication kept up in the steady state (central arrivals /
messages received there), catch-up time = from the central restart until every message received
before it is central (faster than real time when below `--partition`), and the direct run's
figures with ratios, and the CPU each kind of process used in the steady state of both runs
(cores: robot stores, recorders and replicators, publishers, the central store, the whole
machine). Targets: 0 lost, steady-state lag p99 < 5 s, catch-up <
partition. Printed, written to artifacts/bench/fleet.json, plot artifacts/bench/fleet_lag.png.

    scripts/in_env.sh python bench/ros_mongo/fleet_bench.py          # 60 s + 60 s partition
    scripts/in_env.sh python bench/ros_mongo/fleet_bench.py --quick  # 10 s + 10 s, a smoke run
"""
import argparse
import bisect
import json
import math
import os
import re
import shutil
import struct
import sys
import threading
import time
from io import BytesIO
from pathlib import Path

import numpy as np
import requests

from ros_harness import LaunchSet, ManagedProcess, PouchDBServer, RosCore, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ros_mongo_bench_lib import CpuWatch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RATES = {"/odom": 100.0, "/scan": 10.0, "/camera/rgb/image_raw": 5.0}
TOPICS = "[/odom, /scan, /camera/rgb/image_raw]"
#: Steady-state lag counts messages received from 5 s after the start until CUT_GUARD s before the
#: central server is stopped: a message received later may be caught in flight by the cut and
#: carry the partition in its lag. The guard drops a slice of time, not slow messages: one received
#: earlier that still arrives after the cut is counted with its whole (partition-inflated) lag.
CUT_GUARD = 10.0


# -- the publisher (run as `fleet_bench.py --publish SECONDS` under a robot's roscore) ----------

def _samples():
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Image, LaserScan

    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = "odom", "base_link"
    odom.pose.pose.orientation.w = 1.0
    scan = LaserScan(angle_min=-2.356, angle_max=2.356, angle_increment=4.712 / 1080,
                     range_min=0.05, range_max=30.0,
                     ranges=[2.0 + math.sin(i / 50.0) for i in range(1081)],
                     intensities=[100.0] * 1081)
    image = Image(height=480, width=640, encoding="rgb8", step=640 * 3,
                  data=bytes((i * 31) % 251 for i in range(640 * 480 * 3)))
    return {"/odom": odom, "/scan": scan, "/camera/rgb/image_raw": image}


def publish(duration: float, topics) -> int:
    """Publish `topics` (all of RATES when empty) at their rates for `duration` s, once every
    topic has a subscriber; prints the counts as a JSON line."""
    import rospy

    rospy.init_node("fleet_bench_publisher", disable_signals=True)
    messages = {t: m for t, m in _samples().items() if not topics or t in topics}
    publishers = {t: rospy.Publisher(t, type(m), queue_size=200) for t, m in messages.items()}
    while min(p.get_num_connections() for p in publishers.values()) < 1:
        time.sleep(0.05)  # the condition: the recorder subscribed to every topic
    time.sleep(0.5)
    counts = {t: 0 for t in messages}
    start = time.monotonic() + 0.2

    def run(topic):
        buffer = BytesIO()
        messages[topic].serialize(buffer)
        template = bytearray(buffer.getvalue())
        raw = type("Raw", (rospy.AnyMsg,), {"_type": messages[topic]._type,
                                            "_md5sum": messages[topic]._md5sum,
                                            "_full_text": messages[topic]._full_text,
                                            "_has_header": False, "__slots__": []})()
        publisher = rospy.Publisher(topic, type(raw), queue_size=200)
        while publisher.get_num_connections() < 1:
            time.sleep(0.05)
        for index in range(int(duration * RATES[topic])):
            delay = start + index / RATES[topic] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            now = rospy.Time.now()
            struct.pack_into("<III", template, 0, index, now.secs, now.nsecs)
            raw._buff = bytes(template)
            publisher.publish(raw)
            counts[topic] = index + 1

    threads = [threading.Thread(target=run, args=(t,)) for t in messages]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    time.sleep(1.0)
    print(json.dumps({"published": counts}), flush=True)
    return 0


# -- measuring -----------------------------------------------------------------------------------

MESSAGE_ID = re.compile(r"^(\d{19})-")  # message ids start with the receive time in ns


class CentralWatch:
    """Follows the central database: arrival time of every message document.

    Two readers: one samples the database's `update_seq` every 0.1 s (a cheap `GET /db`), the
    other reads the `_changes` feed without documents (the receive time is the first part of a
    message id) for each message's sequence number. A message's arrival time is the first
    sample whose `update_seq` had reached its sequence, so it stays right even when the feed
    reader falls behind a busy server (it was seen 10,000 changes behind). The feed is polled
    (every 0.2 s while nothing is new) rather than held open as a long poll: a long poll sent to
    pouchdb-server right after its restart was seen to stay open for minutes while documents
    arrived. Sizes are read once at the end (`sizes`)."""

    def __init__(self, db_url: str):
        self.db_url = db_url
        self.seen = {}  # id -> (sequence number, receive time, time the feed reader saw it)
        self.samples = []  # (wall time, update_seq), update_seq rising
        self.since = "0"
        self._stop = threading.Event()
        self.threads = [threading.Thread(target=target, daemon=True)
                        for target in (self._follow_feed, self._sample_sequence)]
        for thread in self.threads:
            thread.start()

    def _sample_sequence(self):
        session = requests.Session()
        while not self._stop.is_set():
            try:
                seq = _seq_number(session.get(self.db_url, timeout=30).json()["update_seq"])
            except (requests.RequestException, ValueError, KeyError):
                time.sleep(0.5)  # the central server is down: look again
                continue
            if not self.samples or seq > self.samples[-1][1]:
                self.samples.append((time.time(), seq))
            time.sleep(0.1)

    def _follow_feed(self):
        session = requests.Session()
        while not self._stop.is_set():
            try:
                answer = session.get(self.db_url + "/_changes", timeout=120, params={
                    "since": self.since, "limit": "5000"}).json()
            except (requests.RequestException, ValueError):
                time.sleep(0.5)  # the central server is down: look again
                continue
            if not answer.get("results"):
                time.sleep(0.2)  # nothing new yet
            now = time.time()
            for change in answer.get("results", []):
                match = MESSAGE_ID.match(change["id"])
                if match and not change.get("deleted") and change["id"] not in self.seen:
                    self.seen[change["id"]] = (_seq_number(change["seq"]),
                                               int(match.group(1)) / 1e9, now)
            self.since = str(answer.get("last_seq", self.since))

    @property
    def arrivals(self) -> dict:
        """{message id: (arrival wall time, receive time)}."""
        times = [t for t, _ in self.samples]
        seqs = [q for _, q in self.samples]
        result = {}
        for doc_id, (seq, received, read_at) in list(self.seen.items()):
            index = bisect.bisect_left(seqs, seq)
            result[doc_id] = (min(times[index], read_at) if index < len(times) else read_at, received)
        return result

    def count(self) -> int:
        return len(self.seen)

    def stop(self):
        """Stop both readers (daemon threads: a request in flight does not hold the run)."""
        self._stop.set()
        for thread in self.threads:
            thread.join(timeout=10)

    def sizes(self) -> dict:
        """{message id: stored bytes} of every central message (read once, after the run)."""
        found, start = {}, None
        while True:
            params = {"include_docs": "true", "limit": "1001"}
            if start is not None:
                params["startkey"] = json.dumps(start)
            rows = requests.get(self.db_url + "/_all_docs", params=params, timeout=300).json()["rows"]
            for row in rows[:1000]:
                doc = row.get("doc") or {}
                if doc.get("kind") == "message":
                    found[row["id"]] = doc.get("size", 0)
            if len(rows) <= 1000:
                return found
            start = rows[1000]["id"]


def _seq_number(seq) -> int:
    """A change sequence as a number (pouchdb-server: an integer; CouchDB: "<n>-<opaque>")."""
    return int(str(seq).split("-", 1)[0])


def local_messages(db_url: str) -> int:
    try:
        return requests.get(db_url, timeout=30).json()["doc_count"]
    except (requests.RequestException, ValueError, KeyError):
        return -1


class Robot:
    def __init__(self, index, work: Path, local_topics=()):
        self.robot_id = f"robot{index}"
        self.work = work / self.robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.launches = LaunchSet(self.core, self.work / "launch")
        self.local_topics = list(local_topics)
        self.store = None
        self.publisher = None

    def start_fleet(self, central_url):
        self.store = PouchDBServer(self.work / "store").start()
        self.url = self.store.database_url("robot_data")
        self.nodes = self.launches(str(ROOT / "launch" / "fleet.launch"), central_url=central_url,
                      robot_id=self.robot_id, local_db="true", local_db_server="false",
                      local_db_port=self.store.port,
                      topics=TOPICS, local_topics=_yaml_list(self.local_topics),
                      spool_path=str(self.work / "spool"))

    def start_direct(self, central_db_url):
        topics = [t for t in RATES if t not in self.local_topics]  # what central gets either way
        self.nodes = self.launches(str(ROOT / "launch" / "fleet.launch"), central_url=central_db_url,
                                   robot_id=self.robot_id, topics=_yaml_list(topics),
                                   spool_path=str(self.work / "spool_direct"))

    def publish(self, duration, topics=()):
        """Start the publisher: `topics` (default all) for `duration` s."""
        self.publisher = ManagedProcess([sys.executable, __file__, "--publish", duration,
                                         "--publish-topics", *topics],
                                        name=f"publisher {self.robot_id}",
                                        log_path=self.work / f"publisher_{time.time_ns()}.log",
                                        env=self.core.env()).start()

    def published(self) -> int:
        """Messages published on the topics that go to central."""
        for line in self.publisher.log_path.read_text().splitlines():
            if line.startswith("{"):
                return sum(n for topic, n in json.loads(line)["published"].items()
                           if topic not in self.local_topics)
        raise RuntimeError(f"publisher of {self.robot_id} printed no counts:\n{self.publisher.log_tail()}")

    def close(self):
        if self.publisher is not None:
            self.publisher.stop()
        self.launches.stop_all()
        if self.store is not None:
            self.store.stop()
        self.core.stop()


def _yaml_list(topics) -> str:
    return "[" + ", ".join(topics) + "]"


def _percentiles(values):
    if not values:
        return {"p50": None, "p99": None, "n": 0}
    array = np.asarray(values)
    return {"p50": float(np.percentile(array, 50)), "p99": float(np.percentile(array, 99)),
            "n": int(array.size)}


def _progress(what, watch, expected=None):
    total = f" of {expected}" if expected else ""
    print(f"  {time.strftime('%H:%M:%S')} {what}: {watch.count()}{total} messages central", flush=True)


class SteadyCpu:
    """CPU used in the steady state, in cores (CPU seconds / wall seconds), by kind of process
    (every robot's local store, its roslaunch tree of recorder and replicator, its publisher; the
    central store) and by the whole machine (/proc/stat), between `start()` and `stop()`."""

    def __init__(self, robots, central):
        self.watch = CpuWatch(period=0.5)
        self.kinds = {"central store": ["central"]}
        if central is not None:
            self.watch.add("central", central.process.pid)
        for robot in robots:
            for kind, name, pid in (("robot stores", f"store {robot.robot_id}",
                                     robot.store.process.pid if robot.store else None),
                                    ("recorders and replicators (roslaunch trees)",
                                     f"nodes {robot.robot_id}", robot.nodes.process.pid),
                                    ("publishers", f"publisher {robot.robot_id}", robot.publisher.pid)):
                if pid is not None:
                    self.watch.add(name, pid)
                    self.kinds.setdefault(kind, []).append(name)

    def start(self):
        self.watch.mark("start")
        self.began, self.machine = time.time(), _machine_jiffies()

    def stop(self) -> dict:
        self.watch.sample()
        seconds = time.time() - self.began
        busy, total = (b - a for a, b in zip(self.machine, _machine_jiffies()))
        figures = {kind: sum(self.watch.cpu(name, "start") for name in names) / seconds
                   for kind, names in self.kinds.items()}
        figures["whole machine"] = busy / total * (os.cpu_count() or 1) if total else None
        self.watch.close()
        return {"seconds": seconds, "cores": figures}


def _machine_jiffies():
    """(busy, total) jiffies of all CPUs since boot (/proc/stat; idle and iowait are not busy)."""
    with open("/proc/stat") as stat:
        values = [int(v) for v in stat.readline().split()[1:]]
    return sum(values) - values[3] - values[4], sum(values)


def run_replicated(work: Path, robots_n: int, duration: float, partition: float, tail: float,
                   local_topics=()):
    central = PouchDBServer(work / "central").start()
    central_url = central.database_url("fleet")
    robots = []
    try:
        robots = [Robot(i, work / "replicated", local_topics) for i in range(1, robots_n + 1)]
        for robot in robots:
            robot.start_fleet(central_url)
        wait_until(lambda: requests.get(central_url, timeout=5).ok, 300, what="central database")
        watch = CentralWatch(central_url)
        total = duration + partition + tail
        for robot in robots:
            robot.publish(total)
        t0 = time.time()
        cpu = SteadyCpu(robots, central)
        while time.time() - t0 < duration:
            time.sleep(5)  # progress display while the steady state runs
            _progress("steady", watch)
            if not hasattr(cpu, "began"):
                cpu.start()  # the steady state: from 5 s after the start to the cut
        steady_cpu = cpu.stop()
        central.stop()
        t_cut = time.time()
        print(f"  {time.strftime('%H:%M:%S')} central stopped for {partition:.0f} s", flush=True)
        time.sleep(partition)  # the partition itself: the condition is its length
        central.start()
        t_heal = time.time()
        print(f"  {time.strftime('%H:%M:%S')} central restarted", flush=True)
        wait_until(lambda: not any(r.publisher.alive for r in robots), total + 600,
                   what="publishers done")
        published = sum(r.published() for r in robots)
        _drain(watch, published, "draining")
        sizes = watch.sizes()
        arrivals = [(a, r, sizes.get(i, 0)) for i, (a, r) in list(watch.arrivals.items())]
        steady = [a - r for a, r, _ in arrivals if t0 + 5 <= r < t_cut - CUT_GUARD]
        steady_arrivals = sum(1 for a, *_ in arrivals if t0 + 5 <= a < t_cut)
        steady_received = sum(1 for _, r, _ in arrivals if t0 + 5 <= r < t_cut)
        before_heal = [a for a, r, _ in arrivals if r < t_heal]
        catch_up = max(before_heal) - t_heal if before_heal else None
        window = [(a, s) for a, r, s in arrivals if t_heal <= a <= t_heal + (catch_up or 0)]
        stored = len(arrivals)
        first, last = min(a for a, *_ in arrivals), max(a for a, *_ in arrivals)
        result = {
            "published": published, "central": stored, "lost": published - stored,
            "local": sum(local_messages(r.url) for r in robots),
            "steady_lag_s": _percentiles(steady), "cut_guard_s": CUT_GUARD,
            # central arrivals / messages received in the steady state: below 1, a backlog grows
            "steady_keeping_up": steady_arrivals / steady_received if steady_received else None,
            "catch_up_s": catch_up, "partition_s": partition,
            "catch_up_rate_msgs_per_s": len(window) / catch_up if catch_up else None,
            "catch_up_mb_per_s": sum(s for _, s in window) / 2 ** 20 / catch_up if catch_up else None,
            "central_msgs_per_s_overall": stored / (last - first) if last > first else None,
            "timeline": [(a - t0, a - r) for a, r, _ in sorted(arrivals)][::5],
            "cut_at": t_cut - t0, "heal_at": t_heal - t0,
            "steady_cpu": steady_cpu,
        }
        return result
    finally:
        for robot in robots:
            robot.close()
        central.stop()


def _drain(watch, published: int, label: str) -> None:
    """Wait until central holds every published message or nothing arrived for 600 s, then stop
    watching."""
    last_change, last_count = time.time(), -1
    while watch.count() < published and time.time() - last_change < 600:
        time.sleep(2)
        if watch.count() != last_count:
            last_change, last_count = time.time(), watch.count()
        _progress(label, watch, published)
    watch.stop()


def run_direct(work: Path, robots_n: int, duration: float, local_topics=()):
    central = PouchDBServer(work / "central_direct").start()
    central_url = central.database_url("fleet")
    robots = []
    try:
        robots = [Robot(i, work / "direct", local_topics) for i in range(1, robots_n + 1)]
        for robot in robots:
            robot.start_direct(central_url)  # the recorders create the database
        watch = CentralWatch(central_url)
        for robot in robots:  # nobody subscribes to a local topic in this run
            robot.publish(duration, [t for t in RATES if t not in local_topics])
        t0 = time.time()
        cpu = SteadyCpu(robots, central)
        time.sleep(5)  # the same steady window as the replicated run: from 5 s ...
        cpu.start()
        time.sleep(max(0.0, duration - 7))  # ... to shortly before publishing ends
        steady_cpu = cpu.stop()
        wait_until(lambda: not any(r.publisher.alive for r in robots), duration + 600,
                   what="publishers done")
        published = sum(r.published() for r in robots)
        _drain(watch, published, "direct")
        arrivals = list(watch.arrivals.values())
        lags = [a - r for a, r in arrivals if r >= t0 + 5]
        first, last = min(a for a, *_ in arrivals), max(a for a, *_ in arrivals)
        return {"published": published, "central": len(arrivals),
                "lost": published - len(arrivals), "lag_s": _percentiles(lags),
                "central_msgs_per_s_overall": len(arrivals) / (last - first) if last > first else None,
                "steady_cpu": steady_cpu}
    finally:
        for robot in robots:
            robot.close()
        central.stop()


def plot(result, output: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    timeline = result["replicated"]["timeline"]
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot([t for t, _ in timeline], [lag for _, lag in timeline], ".", ms=2,
            label="replicated: central arrival - receive time")
    ax.axvspan(result["replicated"]["cut_at"], result["replicated"]["heal_at"], color="0.85",
               label="central server down")
    ax.axvspan(result["replicated"]["cut_at"] - CUT_GUARD, result["replicated"]["cut_at"],
               color="0.93", label="not in the steady-state figures (guard)")
    ax.set_xlabel("seconds since the robots started publishing")
    ax.set_ylabel("lag (s)")
    kept = f"; kept local: {', '.join(result['local_topics'])}" if result["local_topics"] else ""
    ax.set_title(f"Fleet replication: {result['robots']} robots -> central (pouchdb-server){kept}")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(output / "fleet_lag.png", dpi=120)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publish", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--publish-topics", nargs="*", default=[], help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="10 s steady + 10 s partition")
    parser.add_argument("--duration", type=float, help="steady-state seconds (default 60)")
    parser.add_argument("--partition", type=float, help="seconds the central server is down (60)")
    parser.add_argument("--tail", type=float, default=20.0, help="seconds published after the partition")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--local-topics", nargs="*", default=[], metavar="TOPIC",
                        help="topics kept on the robots (fleet.launch local_topics), e.g. "
                             "/camera/rgb/image_raw; the direct run then records only the others")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "bench")
    args, _ = parser.parse_known_args()
    if args.publish is not None:
        return publish(args.publish, args.publish_topics)
    duration = args.duration or (10.0 if args.quick else 60.0)
    partition = args.partition or (10.0 if args.quick else 60.0)
    args.output.mkdir(parents=True, exist_ok=True)
    work = args.output / "fleet_work"
    shutil.rmtree(work, ignore_errors=True)
    print(f"replicated run: {args.robots} robots, {duration:.0f} s steady, {partition:.0f} s "
          f"partition, {args.tail:.0f} s after", flush=True)
    if args.local_topics:
        print(f"kept on the robots: {', '.join(args.local_topics)}", flush=True)
    replicated = run_replicated(work, args.robots, duration, partition, args.tail, args.local_topics)
    print(f"direct run: {args.robots} robots writing to the central server for {duration:.0f} s",
          flush=True)
    direct = run_direct(work, args.robots, duration, args.local_topics)
    result = {"robots": args.robots, "rates_hz": RATES, "local_topics": args.local_topics,
              "replicated": replicated, "direct": direct}
    if direct["central_msgs_per_s_overall"] and replicated["catch_up_rate_msgs_per_s"]:
        result["catch_up_rate_over_direct_rate"] = (replicated["catch_up_rate_msgs_per_s"]
                                                    / direct["central_msgs_per_s_overall"])
    if direct["lag_s"]["p99"] and replicated["steady_lag_s"]["p99"]:
        result["steady_lag_p99_over_direct"] = replicated["steady_lag_s"]["p99"] / direct["lag_s"]["p99"]
    (args.output / "fleet.json").write_text(json.dumps(result, indent=1))
    plot(result, args.output)
    shown = {k: v for k, v in replicated.items() if k != "timeline"}
    print(json.dumps({"replicated": shown, "direct": direct,
                      **{k: v for k, v in result.items() if k.endswith("_direct") or
                         k.endswith("direct_rate")}}, indent=1))
    for run, figures in (("replicated", replicated), ("direct", direct)):
        cores = figures["steady_cpu"]["cores"]
        print(f"CPU in the steady state, {run} run (cores of {os.cpu_count()}): " + ", ".join(
            f"{kind} {value:.2f}" for kind, value in cores.items() if value is not None))
    ok = (replicated["lost"] == 0 and direct["lost"] == 0
          and (replicated["steady_lag_s"]["p99"] or 1e9) < 5.0
          and (replicated["catch_up_s"] if replicated["catch_up_s"] is not None else 1e9) < partition)
    print(f"targets (0 lost, steady lag p99 < 5 s, catch-up < {partition:.0f} s): "
          f"{'met' if ok else 'NOT met'}; figures in {args.output / 'fleet.json'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
