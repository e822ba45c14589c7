"""Import and replay stages of bench/ros_mongo/ros_mongo_bench.py (see its docstring)."""

import numpy as np
from ros_mongo_bench_lib import TOPICS, Arrivals, gap_errors, raw_bulk_rate, recorded_times

from ros_harness import ManagedProcess, RosLaunch, wait_until
from ros_mongo import open_store
from ros_mongo.files.bagio import import_bag


def say(text=""):
    print(text, flush=True)


def bench_import(bag, urls, raw_rate=True):
    """The bag imported into each database and, unless not `raw_rate`, the same server's raw
    bulk-insert rate for the same payloads, measured on fresh databases just before and just
    after the import and averaged (seconds per message): a server still compacting what the
    previous stages wrote is slower for whichever comes first."""
    if raw_rate:  # the import as the ros_mongo_bag command line runs it (not for --only-replay, so
        # the replay's measuring subscriber is the same in runs of versions with and without it)
        try:
            from ros_mongo.recording.allocator import keep_freed_memory
            keep_freed_memory()
        except ImportError:  # a ros_mongo without it (comparing with an earlier version)
            pass
    results = {}
    for backend, url in urls.items():
        raw_before = raw_bulk_rate(bag, url + "_raw_before") if raw_rate else None
        with open_store(url + "_import") as store:
            imported = import_bag(bag, store, session_id="import", progress=True)
        if not raw_rate:
            results[backend] = {"import_msgs_per_s": imported.rate, "messages": imported.messages,
                                "import_mb_per_s": imported.megabytes_per_second,
                                "megabytes": imported.bytes / 1e6}
            continue
        raw_after = raw_bulk_rate(bag, url + "_raw_after")
        seconds = (raw_before["seconds"] + raw_after["seconds"]) / 2
        raw = {"msgs_per_s": raw_before["msgs_per_s"] * raw_before["seconds"] / seconds,
               "mb_per_s": raw_before["mb_per_s"] * raw_before["seconds"] / seconds}
        results[backend] = {"raw_before_msgs_per_s": raw_before["msgs_per_s"],
                            "raw_after_msgs_per_s": raw_after["msgs_per_s"],
                            "import_msgs_per_s": imported.rate,
                            "import_mb_per_s": imported.megabytes_per_second,
                            "messages": imported.messages, "megabytes": imported.bytes / 1e6,
                            "raw_msgs_per_s": raw["msgs_per_s"], "raw_mb_per_s": raw["mb_per_s"],
                            "ratio_msgs": imported.rate / raw["msgs_per_s"],
                            "ratio_mb": imported.megabytes_per_second / raw["mb_per_s"]}
    return results


def bench_replay(core, bag, url, work, extra, repeats):
    """The same data through rosbag play and through ros_mongo_retriever, alternately `repeats`
    times (a pair of runs each time, the order alternating); gap errors per topic pooled over the
    runs, each run's p99, and the spread of the pairs' p99 ratios (a p99 of sub-millisecond errors
    moves from run to run: the median pair ratio and its range say how settled the pooled one is)."""
    recorded = recorded_times(bag)
    runs = {"rosbag_play": [], "ros_mongo_retriever": []}
    for run in range(repeats):
        say(f"  replay pair {run + 1}/{repeats}")
        order = ("rosbag_play", "ros_mongo_retriever") if run % 2 == 0 else \
            ("ros_mongo_retriever", "rosbag_play")
        for who in order:
            runs[who].append(_play_rosbag(core, bag, work) if who == "rosbag_play"
                             else _play_retriever(core, url, work, extra, recorded))
    results = {}
    for who, arrivals in runs.items():
        results[who] = gap_errors(arrivals, recorded)
        results[who]["p99_ms_per_run"] = [gap_errors(a, recorded)["all"]["p99_ms"] for a in arrivals]
    ratios = [r / max(b, 1e-9) for r, b in zip(results["ros_mongo_retriever"]["p99_ms_per_run"],
                                                 results["rosbag_play"]["p99_ms_per_run"])]
    pooled = (results["ros_mongo_retriever"]["all"]["p99_ms"]
              / max(results["rosbag_play"]["all"]["p99_ms"], 1e-9))
    results["p99_ratio"] = {
        "pooled": pooled,
        "pairs": ratios, "median_pair": float(np.median(ratios)), "min_pair": min(ratios),
        "max_pair": max(ratios), "pairs_at_most_1": sum(r <= 1.0 for r in ratios)}
    return results


def _play_rosbag(core, bag, work):
    arrivals = Arrivals({f"/play{t}": t for t in TOPICS})
    player = ManagedProcess(["rosbag", "play", "--quiet", "--wait-for-subscribers", "--prefix", "/play",
                             str(bag)], name="rosbag play", log_path=work / "logs" / "rosbag_play.log",
                            env=core.env()).start()
    wait_until(lambda: not player.alive, 600, interval=0.2, what="rosbag play to finish")
    arrivals.close()
    return arrivals.times


def _play_retriever(core, url, work, extra, recorded):
    arrivals = Arrivals({f"{t}_mongo": t for t in TOPICS})
    params = {"db_url": url + "_import", "query": "session_id import", "start_delay": 2.0, "autostart": True}
    retriever = RosLaunch.node("ros_mongo", "ros_mongo_retriever", master_uri=core.uri, log_dir=work / "logs",
                               env=core.env(), params={**params, **extra}).start()
    expected = sum(len(v) for v in recorded.values())
    wait_until(lambda: arrivals.total() >= expected, 600, interval=0.2, what="retriever replay",
               check=retriever.process.check_alive)
    retriever.stop()
    arrivals.close()
    return arrivals.times
