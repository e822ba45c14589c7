#!/usr/bin/env python3
"""Fleet uploads through a capped link: one robot (launch/fleet.launch with upload rules) records
odometry, scans and camera images into a central pouchdb-server behind a real throttling process
(throttle_proxy.py, `--link-mb` MB/s).

Rules: /odom and /scan live; /camera/rgb/image_raw when docked (std_msgs/Bool on /docked, from a
real `rostopic pub`); /bumper (scans at 10 Hz) on_event (before 3 s, after 2 s), triggered twice,
overlapping, by another node on /ros_mongo_server/event. The recorder's own cap
(`upload_max_bytes_per_s`) is 90 % of the link. `rosbag record` of the same topics runs alongside.
At the full rates the live topics as a document per message (about 2.9 MB/s with their decoded
fields) do not fit a 2 MB/s link: they go as chunks (`--chunk-topics`, closed every
`--chunk-period` s) with `--decode` levels (default odometry raw, scans index: about 1.5 MB/s).

Figures: live lag (central arrival minus receive time; CentralWatch of fleet_bench.py) p50 / p99
per topic while the images wait (a chunk's messages: the chunk's arrival minus each one's receive
time); images on central before docking (should be 0) and the time from docking until every image
is central, each once; the event window: messages central, gaps and duplicates, labels; the ledger
(`ros_mongo_bag ledger`) against central's counts per topic; robot CPU of the recorder against
`rosbag record`'s over the same interval (from the first live message central to the end: the
recording and every upload, docking included), and over the recording alone (until every live
message is central). Printed and written to artifacts/bench/fleet_uploads.json.

    scripts/in_env.sh python bench/ros_mongo/fleet_uploads.py --scale 1.0 --duration 20   # as specified
    scripts/in_env.sh python bench/ros_mongo/fleet_uploads.py --scale 0.2 --duration 10   # small
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import requests

from ros_harness import LaunchSet, ManagedProcess, PouchDBServer, RosCore, free_port, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet_bench import CentralWatch, _percentiles  # noqa: E402
from ros_mongo_bench_lib import CpuWatch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
RATES = {"/odom": 1000.0, "/scan": 40.0, "/camera/rgb/image_raw": 30.0, "/bumper": 10.0}
CAMERA = "/camera/rgb/image_raw"
RULES = """\
rules:
  - topics: ^/(odom|scan)$
    upload: live
  - name: camera
    topics: ^/camera/
    upload: when
    when: {docked: /docked}
    max_mb: 8000
  - name: bumper
    topics: ^/bumper$
    upload: on_event
    event: {before: 3.0, after: 2.0}
"""
LONG = 900.0


def publish(duration: float, scale: float) -> int:
    """The publisher process: the topics at RATES x scale for `duration` s (bench_publisher's
    pre-serialized samples, header.seq = index), once each has two subscribers."""
    import rospy
    from bench_publisher import raw_class, run_topic, samples

    rospy.init_node("fleet_uploads_publisher", disable_signals=True)
    messages = samples()
    messages["/bumper"] = messages["/scan"]
    publishers = {t: rospy.Publisher(t, raw_class(m), queue_size=max(100, int(RATES[t])))
                  for t, m in messages.items()}
    while min(p.get_num_connections() for p in publishers.values()) < 2:
        time.sleep(0.05)  # the condition: the recorder and rosbag record subscribed
    time.sleep(0.5)
    counts = {t: 0 for t in messages}
    start = time.monotonic() + 0.5
    threads = [threading.Thread(target=run_topic, args=(t, messages[t], publishers[t], RATES[t] * scale,
                                                         duration, start, counts)) for t in messages]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    time.sleep(1.0)
    print(json.dumps({"published": counts}), flush=True)
    rospy.signal_shutdown("done")
    return 0


def central_docs(db_url):
    """(topic, header.seq or None, tags, message id, document id, receive time) of every central
    message (a chunk's messages each)."""
    found, start = [], None
    while True:
        params = {"include_docs": "true", "limit": "1001"}
        if start is not None:
            params["startkey"] = json.dumps(start)
        rows = requests.get(db_url + "/_all_docs", params=params, timeout=300).json()["rows"]
        for row in rows[:1000]:
            doc = row.get("doc") or {}
            if doc.get("kind") == "message":
                seq = ((doc.get("msg") or {}).get("header") or {}).get("seq")
                found.append((doc["topic"], seq, doc.get("tags", []), row["id"], row["id"],
                              doc["receive_time"]))
            elif doc.get("kind") == "chunk":
                found += [(doc["topic"], None, doc.get("tags", []), message_id, row["id"],
                           secs + nsecs * 1e-9)
                          for message_id, secs, nsecs in zip(doc["ids"], doc["secs"], doc["nsecs"])]
        if len(rows) <= 1000:
            return found
        start = rows[1000]["id"]


def per_topic(docs):
    counts = {}
    for topic, *_ in docs:
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def ledger(spool):
    result = subprocess.run([sys.executable, str(ROOT / "src/ros_mongo/scripts/ros_mongo_bag"), "ledger",
                             str(spool)], capture_output=True, text=True, timeout=120)
    rows = [line.split() for line in result.stdout.splitlines()[1:]]
    return {row[0]: dict(zip(("recorded", "uploaded", "dropped", "recycled", "waiting"),
                             map(int, row[1:6]))) for row in rows}


def run(args) -> dict:
    work = Path(tempfile.mkdtemp(prefix="fleet_uploads_"))
    central = PouchDBServer(work / "central").start()
    admin_url = central.database_url("fleet")
    requests.put(admin_url, timeout=60).raise_for_status()
    port = free_port()
    proxy = ManagedProcess([sys.executable, str(HERE / "throttle_proxy.py"), "--port", str(port),
                            "--upstream", central.url.split("//")[1],
                            "--bytes-per-s", str(args.link_mb * 1e6)],
                           name="throttle proxy", log_path=work / "proxy.log").start()
    wait_until(lambda: "throttle proxy on" in proxy.log_path.read_text(), 60, what="the proxy")
    core = RosCore(log_dir=work / "ros").start()
    launches = LaunchSet(core, work / "launch")
    rules = work / "rules.yaml"
    rules.write_text(RULES)
    spool = work / "recorder.spool"
    processes = []
    cpu = CpuWatch()
    try:
        def pub(*argv):
            process = ManagedProcess(["rostopic", "pub", *map(str, argv)], name="rostopic pub",
                                     log_path=work / f"pub_{time.time_ns()}.log", env=core.env()).start()
            processes.append(process)
            return process

        undocked = pub("/docked", "std_msgs/Bool", "data: false", "-r", "2")
        recorder = launches(str(ROOT / "launch" / "fleet.launch"),
                            central_url=f"http://127.0.0.1:{port}/fleet", robot_id="robot1",
                            topics="[" + ", ".join(RATES) + "]", spool_path=str(spool),
                            upload_rules=str(rules), upload_max_bytes_per_s=str(0.9 * args.link_mb * 1e6),
                            chunk_topics=args.chunk_topics, chunk_period=str(args.chunk_period),
                            decode=args.decode)
        recorder.wait_for_subscribers(list(RATES) + ["/docked"], timeout=LONG)
        rosbag = ManagedProcess(["rosbag", "record", "-O", str(work / "same.bag"), *RATES], name="rosbag",
                                log_path=work / "rosbag.log", env=core.env()).start()
        processes.append(rosbag)  # stopped at the end with the others (it outlived the run before)
        cpu.add("recorder", recorder.node_pid("/ros_mongo_server"))
        cpu.add("rosbag", rosbag.pid)
        watch = CentralWatch(admin_url)
        publisher = ManagedProcess([sys.executable, __file__, "--publish", str(args.duration),
                                    "--scale", str(args.scale)],
                                   name="publisher", log_path=work / "publisher.log", env=core.env()).start()
        processes.append(publisher)
        wait_until(lambda: per_topic(central_docs(admin_url)).get("/odom", 0) > 0, LONG, interval=0.5,
                   what="publishing")
        cpu.mark("start")
        started = time.time()
        time.sleep(args.duration / 2)  # the publishing schedule: trigger in the middle, twice
        triggers = [time.time()]
        pub("/ros_mongo_server/event", "std_msgs/String", "data: bump", "-1")
        time.sleep(1.0)
        triggers.append(time.time())
        pub("/ros_mongo_server/event", "std_msgs/String", "data: stall", "-1")
        wait_until(lambda: not publisher.alive, LONG, what="everything published")
        published = json.loads(publisher.log_path.read_text().strip().splitlines()[-1])["published"]
        live = published["/odom"] + published["/scan"]
        wait_until(lambda: sum(per_topic(central_docs(admin_url)).get(t, 0) for t in ("/odom", "/scan"))
                   >= live, LONG, interval=2.0, what="every live message central")
        recording_cpu = {name: round(cpu.cpu(name, "start"), 2) for name in ("recorder", "rosbag")}
        before_dock = per_topic(central_docs(admin_url))
        arrivals = watch.arrivals
        lag = {topic: _percentiles([arrivals[d[4]][0] - d[5] for d in central_docs(admin_url)
                                    if d[0] == topic and d[4] in arrivals])
               for topic in ("/odom", "/scan", "/bumper")}
        undocked.stop()
        docked_at = time.time()
        pub("/docked", "std_msgs/Bool", "data: true", "-r", "2")
        wait_until(lambda: per_topic(central_docs(admin_url)).get(CAMERA, 0) >= published[CAMERA], LONG,
                   interval=1.0, what="every image central after docking")
        images_after = time.time() - docked_at
        final = central_docs(admin_url)
        ids = [d[3] for d in final]
        keys = [(d[0], d[1]) for d in final if d[1] is not None]
        bumper = sorted((d[1], sorted(d[2])) for d in final if d[0] == "/bumper")
        seqs = [s for s, _ in bumper]
        time.sleep(6.0)  # two ledger periods (5 s): the last counts saved
        book = ledger(spool)
        counts = per_topic(final)
        result = {
            "scale": args.scale, "duration_s": args.duration, "link_mb_per_s": args.link_mb,
            "published": published, "central": counts,
            "duplicates": len(ids) - len(set(ids)) + len(keys) - len(set(keys)),
            "chunk_topics": args.chunk_topics, "chunk_period_s": args.chunk_period, "decode": args.decode,
            "images_central_before_docking": before_dock.get(CAMERA, 0),
            "live_lag_s": lag, "images_all_central_after_docking_s": round(images_after, 1),
            "event": {"messages": len(seqs),
                      "gapless": bool(seqs) and seqs == list(range(seqs[0], seqs[-1] + 1)),
                      "both_labels": sum(tags == ["event:bump", "event:stall"] for _, tags in bumper),
                      "trigger_gap_s": round(triggers[1] - triggers[0], 2)},
            "ledger": book,
            "ledger_equals_central": all(book.get(t, {}).get("uploaded") == n for t, n in counts.items()),
            "cpu_s": {"recorder": round(cpu.cpu("recorder", "start"), 2),
                      "rosbag_record": round(cpu.cpu("rosbag", "start"), 2),
                      "recording_only": recording_cpu},
            "wall_s": round(time.time() - started, 1),
        }
        result["cpu_ratio"] = round(result["cpu_s"]["recorder"]
                                    / max(result["cpu_s"]["rosbag_record"], 1e-9), 2)
        result["cpu_ratio_recording_only"] = round(recording_cpu["recorder"]
                                                   / max(recording_cpu["rosbag"], 1e-9), 2)
        result["load_average"] = [round(v, 2) for v in os.getloadavg()]
        watch.stop()
        return result
    finally:
        cpu.close()
        for process in processes:
            process.stop()
        launches.stop_all()
        core.stop()
        proxy.stop()
        central.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--publish", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--scale", type=float, default=1.0, help="rates x this (1.0: as specified)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of publishing")
    parser.add_argument("--link-mb", type=float, default=2.0, help="the link's cap, MB/s")
    parser.add_argument("--chunk-topics", default="[/odom, /scan]", help="fleet.launch chunk_topics")
    parser.add_argument("--chunk-period", type=float, default=0.25, help="fleet.launch chunk_period")
    parser.add_argument("--decode", default="{odom: raw, scan: index}", help="fleet.launch decode")
    args = parser.parse_args()
    if args.publish is not None:
        return publish(args.publish, args.scale)
    result = run(args)
    print(json.dumps(result, indent=1))
    out = ROOT / "artifacts" / "bench" / "fleet_uploads.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
