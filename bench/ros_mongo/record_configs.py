"""The recording stages of bench/ros_mongo/ros_mongo_bench.py: each robot-side configuration records
the standard load beside `rosbag record` of the same topics, at the same time, in the same run.

Configurations (the database servers run on this machine; the robot side is what runs on the
robot in each configuration):
- `remote_<backend>`: ros_mongo_server writing to a database on another machine (robot side: the
  recorder); `remote_couchdb_chunked` the same with odometry and scans stored as chunks
  (`~chunk_topics`, ros_mongo.storage.chunks);
- `fleet_default`: launch/fleet.launch as shipped, straight to the central CouchDB database with
  the spool as the buffer (robot side: the recorder);
- `fleet_local_store`: fleet.launch local_db:=true: a local pouchdb-server and the replicator
  pushing it to central (robot side: recorder + local store + replicator).
The fault runs (`fault_run`, `full_spool_run`) put ros_harness.fault_proxy between fleet.launch's
recorder and central.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import requests
from ros_mongo_bench_lib import (
    TOPICS,
    CpuWatch,
    RecorderWatch,
    bag_counts,
    peak_rss_mb,
    subscribers_ready,
)

from ros_harness import FaultProxy, LaunchSet, ManagedProcess, PouchDBServer, wait_until
from ros_mongo import open_store

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
FLEET_LAUNCH = str(ROOT / "launch" / "fleet.launch")
CONFIGS = ("remote_couchdb", "remote_couchdb_chunked", "remote_mongodb", "fleet_default", "fleet_local_store")
CHUNK_TOPICS = ["/odom", "/scan"]
TITLES = {"remote_couchdb": "recorder -> database on another machine (CouchDB)",
          "remote_couchdb_chunked": "recorder -> CouchDB elsewhere, odometry and scans as chunks",
          "remote_mongodb": "recorder -> database on another machine (MongoDB)",
          "fleet_default": "fleet default: recorder -> central, spool as buffer",
          "fleet_local_store": "fleet local_db:=true: recorder -> local store -> replication"}
TOPIC_LIST = "[" + ", ".join(TOPICS) + "]"


def say(text=""):
    print(text, flush=True)


def publish(core, duration, subscribers, *, wait=True):
    """The standard load from a process of its own (ros_mongo_bench.py --publish)."""
    command = [sys.executable, str(HERE / "ros_mongo_bench.py"), "--publish", str(duration),
               "--wait-subscribers", str(subscribers)]
    if not wait:
        return subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=core.env())
    done = subprocess.run(command, capture_output=True, text=True, env=core.env(), timeout=duration + 120)
    if done.returncode != 0:
        raise RuntimeError(f"publisher failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _node_pid(launch, node):
    """The pid of `node` once the master knows the running one (a node of the previous
    configuration with the same name may still be registered for a moment)."""
    found = []

    def lookup():
        try:
            found.append(launch.node_pid(node))
            return True
        except Exception:  # noqa: BLE001 - the master or the old node's address: ask again
            return False

    wait_until(lookup, 120, interval=0.2, what=f"{node} registered")
    return found[-1]


def _start(name, core, servers, work):
    """Start configuration `name`: (launches, robot-side pids by role, the database to count in,
    extra processes to stop afterwards)."""
    launches = LaunchSet(core, work / "logs" / name)
    spool = str(work / f"{name}.spool")
    if name.startswith("remote_"):
        url = servers[name.split("_")[1]].database_url(f"bench_{name}")
        chunks = {"chunk_topics": CHUNK_TOPICS} if name.endswith("_chunked") else {}
        launch = launches.node("ros_mongo", "ros_mongo_server", params={
            "db_url": url, "topics": list(TOPICS), "session_id": f"bench_{name}", "spool_path": spool,
            "robot_id": "bench_robot", "diagnostics_period": 0.5, "shutdown_timeout": 120.0, **chunks})
        return launches, {"recorder": _node_pid(launch, "/ros_mongo_server")}, url, []
    url = servers["couchdb"].database_url(f"bench_{name}")
    if name == "fleet_default":
        launch = launches(FLEET_LAUNCH, central_url=url, robot_id="bench_robot", topics=TOPIC_LIST,
                          spool_path=spool)
        return launches, {"recorder": _node_pid(launch, "/ros_mongo_server")}, url, []
    store = PouchDBServer(work / "robot_store").start()
    launch = launches(FLEET_LAUNCH, central_url=url, robot_id="bench_robot", topics=TOPIC_LIST,
                      spool_path=spool, local_db="true", local_db_server="false",
                      local_db_port=str(store.port))
    pids = {"recorder": _node_pid(launch, "/ros_mongo_server"), "robot_store": store.process.pid,
            "replicator": _node_pid(launch, "/ros_mongo_replicator")}
    return launches, pids, url, [store]


def record_config(core, servers, work, duration, name):
    """One configuration beside rosbag record: stored per s, drops, CPU and peak RSS per process."""
    bag = work / f"record_{name}.bag"
    launches, pids, url, extra = _start(name, core, servers, work)
    rosbag = ManagedProcess(["rosbag", "record", "-O", str(bag), *TOPICS], name="rosbag record",
                            log_path=work / "logs" / f"rosbag_record_{name}.log", env=core.env()).start()
    watch = RecorderWatch()
    try:
        wait_until(lambda: subscribers_ready(core.uri, TOPICS, 2), 60, what="recorder and rosbag subscribed")
        cpu = CpuWatch()
        for role, pid in pids.items():
            cpu.add(role, pid)
        server = servers["couchdb" if not name.endswith("mongodb") else "mongodb"]
        cpu.add("central", server.process.pid)
        cpu.add("rosbag", rosbag.pid)
        cpu.mark("start")
        published = publish(core, duration, 2)
        at_end, ended = dict(watch.values), time.monotonic()
        total = sum(published["published"].values())
        wait_until(lambda: watch.count("stored") + watch.count("dropped") >= watch.count("received") > 0
                   and watch.count("spool_pending") == 0 and watch.count("queued") == 0
                   and watch.count("received") >= total * 0.5, 600, what="recorder caught up")
        if "robot_store" in pids:  # what counts is central holding it: wait for the replication
            wait_until(lambda: _central_messages(url) >= watch.count("stored"), 900, interval=0.5,
                       what="central caught up")
        drain = time.monotonic() - ended
        launches.stop_all()
        os.killpg(rosbag.pid, signal.SIGINT)  # the wrapper and its `record` child: the bag gets its index
        wait_until(lambda: bag.exists() and not Path(str(bag) + ".active").exists(), 120, interval=0.2,
                   what="rosbag record to close the bag")
        rosbag.stop(timeout=10)
        cpu.close()
    finally:
        watch.close()
        launches.stop_all()
        for process in extra:
            process.stop()
    with open_store(url) as store:
        stored = {t: store.count_messages(topic=t) for t in TOPICS}
    seconds = published["seconds"]
    result = {"title": TITLES[name], "published": published["published"], "seconds": seconds,
              "recorder": _rates(stored, published["published"], seconds),
              "rosbag": _rates(bag_counts(bag), published["published"], seconds),
              "stored_while_publishing": watch.count_at(at_end, "stored"),
              "drain_seconds_after_publishing": drain, "bag": str(bag), "timeline": watch.timeline,
              "megabytes": bag.stat().st_size / 1e6, "spooled": watch.count_at(watch.values, "spooled")}
    rosbag_rate = max(result["rosbag"]["stored_per_s"], 1e-9)
    result["ratio_stored_per_s"] = result["recorder"]["stored_per_s"] / rosbag_rate
    result["sustained_per_s"] = result["recorder"]["stored_total"] / (seconds + drain)
    result["ratio_sustained"] = result["sustained_per_s"] / rosbag_rate
    result["cpu"] = _cpu_figures(cpu, list(pids), result["megabytes"])
    return result


def _central_messages(url):
    """Messages in a CouchDB database (documents minus the topic documents)."""
    try:
        info = requests.get(url, timeout=10).json()
        topics = requests.get(url + "/_all_docs", params={"startkey": '"topic-"', "endkey": '"topic-\ufff0"'},
                              timeout=10).json()["rows"]
        return int(info["doc_count"]) - len(topics)
    except (requests.RequestException, ValueError, KeyError):
        return -1


def _cpu_figures(cpu, roles, megabytes):
    """CPU seconds (user + system) from the start of publishing until each process exited or the
    run ended, per robot-side role and in all ("robot_side"), of the central database server
    (elsewhere in a real fleet) and of rosbag record's `record` process; multiples of rosbag
    record's; peak RSS of each."""
    seconds = {role: cpu.cpu(role, "start") for role in roles}
    seconds["robot_side"] = sum(seconds[role] for role in roles)
    seconds["central"] = cpu.cpu("central", "start")
    seconds["rosbag_record"] = cpu.cpu("rosbag", "start", command="record")
    seconds["rosbag_all"] = cpu.cpu("rosbag", "start")
    rosbag = max(seconds["rosbag_record"], 1e-9)
    rss = {role: cpu.peak_rss_mb(role) for role in roles}
    rss["rosbag_record"] = cpu.peak_rss_mb("rosbag", command="record")
    return {"seconds": seconds, "per_mb": {k: v / megabytes for k, v in seconds.items()},
            "x_rosbag_record": {k: v / rosbag for k, v in seconds.items()}, "peak_rss_mb": rss}


def _rates(stored, published, seconds):
    return {"stored": stored, "stored_total": sum(stored.values()),
            "stored_per_s": sum(stored.values()) / seconds,
            "drops": {t: published[t] - stored.get(t, 0) for t in published},
            "drops_total": sum(published[t] - stored.get(t, 0) for t in published)}


def fault_run(core, server, work, fault_seconds, *, spool_max_mb=None, settle=5.0):
    """fleet.launch's default recorder through the fault proxy: `fault_seconds` of 401 (a rotated
    password), then of 500 timeout, then recovered (`spool_max_mb` None: the default spool);
    or, with `spool_max_mb`, 2 x `fault_seconds` of central answering 500 timeout into a spool of
    that size. Lost per topic (published - central) against dropped per topic on /diagnostics."""
    logs = work / "logs"
    label = "full_spool" if spool_max_mb else "fault"
    proxy = FaultProxy(server.url, logs / f"proxy_{label}").start()
    url = proxy.database_url(f"bench_{label}")
    launches = LaunchSet(core, logs / label)
    args = dict(central_url=url, robot_id=f"robot_{label}", topics=TOPIC_LIST,
                spool_path=str(work / f"{label}.spool"))
    if spool_max_mb:
        args["spool_max_mb"] = str(spool_max_mb)
    launch = launches(FLEET_LAUNCH, **args)
    watch = RecorderWatch()
    try:
        wait_until(lambda: subscribers_ready(core.uri, TOPICS, 1), 60, what="recorder subscribed")
        pid = _node_pid(launch, "/ros_mongo_server")
        duration = settle + 2 * fault_seconds + settle
        publisher = publish(core, duration, 1, wait=False)
        schedule = ([(settle, {"timeout": "all"}, "500 timeout (central unreachable)")] if spool_max_mb else
                    [(settle, {"auth": "wrong_password"}, "401 wrong password"),
                     (settle + fault_seconds, {"timeout": "writes"}, "500 timeout")])
        schedule.append((settle + 2 * fault_seconds, {}, "recovered"))
        started, peak_pending, recovered_at = time.monotonic(), 0, None
        for at, faults, what in schedule:
            while time.monotonic() - started < at:
                peak_pending = max(peak_pending, watch.count("spool_pending"))
                time.sleep(0.2)
            proxy.set(**faults)
            say(f"  t={time.monotonic() - started:5.1f} s: {what} (stored {watch.count('stored')}, "
                f"spool_pending {watch.count('spool_pending')}, dropped {watch.count('dropped')})")
            recovered_at = time.monotonic()
        out, _ = publisher.communicate(timeout=duration + 300)
        published = json.loads(out.strip().splitlines()[-1])["published"]
        total = sum(published.values())
        wait_until(lambda: watch.count("received") >= total * 0.5 and watch.count("spool_pending") == 0
                   and watch.count("queued") == 0
                   and watch.count("stored") + watch.count("dropped") + watch.count("rejected")
                   >= watch.count("received"), 900, interval=0.2, what="the spool drained")
        drained = time.monotonic() - recovered_at
        peak_mb = peak_rss_mb(pid)
        final = dict(watch.values)
    finally:
        launches.stop_all()
        watch.close()
        proxy.stop()
    with open_store(server.database_url(f"bench_{label}")) as store:
        stored = {t: store.count_messages(topic=t) for t in TOPICS}
    dropped = {t: int(final.get(f"dropped {t}", 0)) for t in TOPICS}
    return {"fault_seconds": fault_seconds, "spool_max_mb": spool_max_mb, "published": published,
            "stored": stored, "lost": {t: published[t] - stored[t] for t in TOPICS},
            "lost_total": sum(published[t] - stored[t] for t in TOPICS), "dropped_counted": dropped,
            "every_loss_counted": all(published[t] - stored[t] == dropped[t] for t in TOPICS),
            "drain_seconds_after_recovery": drained, "peak_rss_mb": peak_mb,
            "peak_spool_pending": peak_pending,
            "counts": {k: final.get(k) for k in ("received", "stored", "dropped", "rejected", "quarantined",
                                                 "spooled", "writer_restarts", "spool_mb")}}
