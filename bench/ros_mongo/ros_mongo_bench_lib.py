"""Helpers of bench/ros_mongo/ros_mongo_bench.py (and fleet_bench.py): servers, watchers, CPU per
process, counts, raw bulk rates, gap errors, plots."""
import base64
import json
import os
import struct
import threading
import time
from pathlib import Path
from typing import Optional

import numpy as np

from ros_harness import MongoWireServer, PouchDBServer, master_graph

BACKENDS = ("couchdb", "mongodb")
TOPICS = ("/odom", "/camera/rgb/image_raw", "/scan")
BLOB = 256 * 1024


def start_servers(work: Path, backends):
    servers = {}
    if "couchdb" in backends:
        servers["couchdb"] = PouchDBServer(work / "couchdb").start()
    if "mongodb" in backends:
        servers["mongodb"] = MongoWireServer(work / "mongodb").start()
    return servers


def subscribers_ready(master_uri, topics, count):
    state = dict(master_graph(master_uri).getSystemState()[1])
    return all(len(state.get(t, [])) >= count for t in topics)


class RecorderWatch:
    """The recorder's counts from /diagnostics, with a timeline for the plot."""

    def __init__(self):
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray

        self.values, self.timeline, self.started = {}, [], time.monotonic()
        self.subscriber = rospy.Subscriber("/diagnostics", DiagnosticArray, self._receive)

    def _receive(self, msg):
        for status in msg.status:
            if status.name == "ros_mongo_server: recorder":
                self.values = {kv.key: kv.value for kv in status.values}
                self.timeline.append((time.monotonic() - self.started, self.count("received"),
                                      self.count("stored"), self.count("queued")))

    def count(self, key):
        return self.count_at(self.values, key)

    @staticmethod
    def count_at(values, key):
        return int(values.get(key, 0))

    def close(self):
        self.subscriber.unregister()


def peak_rss_mb(pid: int) -> float:
    """The peak resident memory (VmHWM) of a running process, in MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmHWM for process {pid}")


_TICKS = os.sysconf("SC_CLK_TCK")


def _stat(pid: int):
    """(parent pid, CPU seconds user+system, command name) of a live process, None once gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) "; comm may hold spaces
    command = text[text.index("(") + 1:text.rindex(")")]
    return int(fields[1]), (int(fields[11]) + int(fields[12])) / _TICKS, command


def _vm_hwm_mb(pid: int) -> float:
    try:
        return peak_rss_mb(pid)
    except (OSError, RuntimeError):  # gone meanwhile, or a zombie
        return 0.0


class CpuWatch:
    """CPU seconds (user+system, /proc/<pid>/stat) and peak RSS (VmHWM) of named processes and
    all their descendants, sampled every `period` s by a thread, so a process's last figures are
    known even after it exited (at most `period` s of its work missed). `mark(label)` keeps each
    process's CPU at that moment; `cpu(name, since)` is the CPU used since a mark."""

    def __init__(self, period: float = 0.1):
        self.period = period
        self.roots = {}        # name -> root pid
        self.seen = {}         # name -> {pid: latest cpu seconds}
        self.peak = {}         # name -> {pid: peak rss MB}
        self.comm = {}         # pid -> command name
        self.marks = {}        # label -> {pid: cpu seconds}
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="cpu_watch", daemon=True)
        self.thread.start()

    def add(self, name: str, pid: int) -> None:
        with self.lock:
            self.roots[name] = pid
            self.seen.setdefault(name, {})
            self.peak.setdefault(name, {})
        self.sample()

    def sample(self) -> None:
        stats = {}
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                stat = _stat(int(entry))
                if stat is not None:
                    stats[int(entry)] = stat
        children = {}
        for pid, (parent, _, _) in stats.items():
            children.setdefault(parent, []).append(pid)
        with self.lock:
            for name, root in self.roots.items():
                todo, tree = [root], []
                while todo:
                    pid = todo.pop()
                    if pid in stats:
                        tree.append(pid)
                        todo += children.get(pid, [])
                for pid in tree:
                    self.seen[name][pid] = stats[pid][1]
                    self.comm[pid] = stats[pid][2]
                    self.peak[name][pid] = max(self.peak[name].get(pid, 0.0), _vm_hwm_mb(pid))

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self.sample()

    def mark(self, label: str) -> None:
        """Keep every watched process's CPU seconds now, under `label`."""
        self.sample()
        with self.lock:
            self.marks[label] = {pid: cpu for seen in self.seen.values() for pid, cpu in seen.items()}

    def cpu(self, name: str, since: str, command: Optional[str] = None) -> float:
        """CPU seconds `name` (and descendants; only `command` ones when given) used since a mark."""
        before = self.marks[since]
        with self.lock:
            return sum(cpu - before.get(pid, 0.0) for pid, cpu in self.seen.get(name, {}).items()
                       if command is None or self.comm.get(pid) == command)

    def peak_rss_mb(self, name: str, command: Optional[str] = None) -> float:
        """Peak resident memory (VmHWM, MB) of the largest process of `name`'s tree (of those
        named `command` when given)."""
        with self.lock:
            return max((mb for pid, mb in self.peak.get(name, {}).items()
                        if command is None or self.comm.get(pid) == command), default=0.0)

    def close(self) -> None:
        self._stop.set()
        self.thread.join()
        self.sample()


def _seq(raw: bytes) -> int:
    return struct.unpack_from("<I", raw, 0)[0]  # header.seq: the publisher's index


class Arrivals:
    """Arrival times (monotonic) per original topic and header.seq."""

    def __init__(self, mapping):
        import rospy

        self.times = {t: {} for t in mapping.values()}
        self.lock = threading.Lock()
        self.subscribers = [rospy.Subscriber(out, rospy.AnyMsg, self._receive, callback_args=topic,
                                             buff_size=1 << 24, tcp_nodelay=True)
                            for out, topic in mapping.items()]

    def _receive(self, msg, topic):
        now = time.monotonic()
        with self.lock:
            self.times[topic][_seq(msg._buff)] = now

    def total(self):
        return sum(len(v) for v in self.times.values())

    def close(self):
        for subscriber in self.subscribers:
            subscriber.unregister()


def _bag_messages(bag_path):
    import rosbag

    with rosbag.Bag(str(bag_path)) as bag:
        for topic, raw, stamp in bag.read_messages(raw=True):
            yield topic, bytes(raw[1]), stamp


def bag_counts(bag_path):
    import rosbag

    with rosbag.Bag(str(bag_path)) as bag:
        return {t: bag.get_message_count(t) for t in TOPICS}


def recorded_times(bag_path):
    times = {t: {} for t in TOPICS}
    for topic, raw, stamp in _bag_messages(bag_path):
        times[topic][_seq(raw)] = stamp.to_sec()
    return times


def gap_errors(runs, recorded):
    """|received gap - recorded gap| over consecutive message pairs that both arrived, pooled over
    runs (one run: a dict topic -> {seq: arrival time}; or a list of them)."""
    runs = runs if isinstance(runs, list) else [runs]
    result, everything = {}, []
    for topic, expected in recorded.items():
        seqs = sorted(expected)
        errors, received = [], 0
        for arrivals in runs:
            got = arrivals.get(topic, {})
            received += len(got)
            errors += [abs((got[b] - got[a]) - (expected[b] - expected[a]))
                       for a, b in zip(seqs, seqs[1:]) if a in got and b in got]
        everything += errors
        result[topic] = _summary(errors, received, len(expected) * len(runs))
    result["all"] = _summary(everything, sum(r["received"] for r in result.values()),
                             sum(len(v) for v in recorded.values()) * len(runs))
    result["all"]["errors_ms"] = [round(e * 1000, 4) for e in everything[:: max(1, len(everything) // 5000)]]
    return result


def _summary(errors, received, expected):
    values = np.array(errors) * 1000.0 if errors else np.array([float("nan")])
    return {"p50_ms": float(np.percentile(values, 50)), "p99_ms": float(np.percentile(values, 99)),
            "mean_ms": float(values.mean()), "pairs": len(errors), "received": received, "expected": expected}


def raw_bulk_rate(bag_path, url):
    """The server's own bulk-insert rate for the bag's payloads in minimal documents
    (same batching as ros_mongo: inline up to 256 KiB, attachments / GridFS above)."""
    messages = list(_bag_messages(bag_path))
    size = sum(len(raw) for _, raw, _ in messages)
    seconds = _raw_couch(messages, url) if url.startswith("http") else _raw_mongo(messages, url)
    return {"msgs_per_s": len(messages) / seconds, "mb_per_s": size / 1e6 / seconds, "seconds": seconds}


def _raw_couch(messages, url):
    import requests

    session = requests.Session()
    session.put(url).raise_for_status()
    bodies, batch, batch_size = [], [], 0
    for index, (topic, raw, stamp) in enumerate(messages):
        doc = {"_id": f"{index:012d}", "topic": topic, "t": stamp.to_sec()}  # sequential: the best case
        encoded = base64.b64encode(raw).decode()
        if len(raw) > BLOB:
            doc["_attachments"] = {"raw": {"content_type": "application/octet-stream", "data": encoded}}
        else:
            doc["raw"] = encoded
        body = json.dumps(doc)
        if batch and (batch_size + len(body) > 24 * 2 ** 20 or len(batch) >= 1000):
            bodies.append("{\"docs\":[" + ",".join(batch) + "]}")
            batch, batch_size = [], 0
        batch.append(body)
        batch_size += len(body)
    bodies.append("{\"docs\":[" + ",".join(batch) + "]}")
    started = time.monotonic()
    for body in bodies:
        session.post(url + "/_bulk_docs", data=body.encode(),
                     headers={"Content-Type": "application/json"}).raise_for_status()
    return time.monotonic() - started


def _raw_mongo(messages, url):
    import gridfs
    import pymongo
    from bson.binary import Binary
    from pymongo.write_concern import WriteConcern

    client = pymongo.MongoClient(url)
    db = client.get_default_database()
    durable = WriteConcern(w=1, j=True)
    collection = db.get_collection("raw", write_concern=durable)
    bucket = gridfs.GridFSBucket(db, bucket_name="rawblobs", write_concern=durable)
    started = time.monotonic()
    batch, batch_size = [], 0
    for index, (topic, raw, stamp) in enumerate(messages):
        doc = {"_id": f"{index:012d}", "topic": topic, "t": stamp.to_sec()}  # sequential: the best case
        if len(raw) > BLOB:
            bucket.upload_from_stream_with_id(doc["_id"], doc["_id"], raw)
        else:
            doc["raw"] = Binary(raw)
            batch_size += len(raw)
        batch.append(doc)
        if len(batch) >= 1000 or batch_size > 32 * 2 ** 20:
            collection.insert_many(batch, ordered=False)
            batch, batch_size = [], 0
    if batch:
        collection.insert_many(batch, ordered=False)
    seconds = time.monotonic() - started
    client.close()
    return seconds


def plot_results(results, output: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    records = results.get("record", {})
    names = list(records)
    cpu = [records[n]["cpu"]["x_rosbag_record"]["robot_side"] for n in names]
    axes[0].bar(range(len(names)), cpu, color="tab:blue")
    axes[0].axhline(1.0, color="tab:gray", ls="--", label="rosbag record (same run)")
    axes[0].axhline(1.3, color="tab:red", ls=":", label="target for the fleet default")
    axes[0].set_xticks(range(len(names)), [n.replace("_", "\n", 1) for n in names], fontsize=8)
    axes[0].set_ylabel("robot-side CPU s / rosbag record's")
    axes[0].set_title("recording 1 kHz odom + 30 Hz images + 40 Hz scans")
    axes[0].legend(fontsize=8)
    for backend, rec in records.items():  # (one line per configuration)
        line = np.array(rec["timeline"]) if rec["timeline"] else np.zeros((0, 4))
        if len(line):
            axes[1].plot(line[:, 0], line[:, 1], label=f"received ({backend})")
            axes[1].plot(line[:, 0], line[:, 2], "--", label=f"stored ({backend})")
    axes[1].set_xlabel("s")
    axes[1].set_ylabel("messages")
    axes[1].set_title("ros_mongo_server counts (/diagnostics)")
    if records:
        axes[1].legend(fontsize=8)
    for who, rep in results.get("replay", {}).items():
        if "all" not in rep:  # the pair ratios
            continue
        errors = np.sort(np.array(rep["all"]["errors_ms"]))
        if len(errors):
            label = f"{who} (p99 {rep['all']['p99_ms']:.2f} ms)"
            axes[2].plot(errors, np.linspace(0, 1, len(errors)), label=label)
    axes[2].set_xscale("log")
    axes[2].set_xlabel("inter-message gap error (ms)")
    axes[2].set_ylabel("fraction of message pairs")
    axes[2].set_title("replay timing")
    axes[2].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(output / "ros_mongo_bench.png", dpi=110)
    plt.close(figure)
