#!/usr/bin/env python3
"""ros_mongo benchmark, in one run on this machine (`python bench/ros_mongo_bench.py [--quick]`):

1. record: ros_mongo_server against `rosbag record`, both subscribed to the same publishers at the
   same time (1 kHz Odometry, 30 Hz 640x480 rgb8 Image, 40 Hz 1081-beam LaserScan): messages stored
   per second, drops (published - stored), ratio to rosbag; per database backend. CPU seconds
   (user+system, from /proc, sampled every 0.1 s until each process exits) of the recorder, of the
   database server it writes to and of rosbag record's `record` process, from the start of
   publishing: totals, per MB published, as multiples of rosbag record's (targets: recorder +
   server <= 3x, recorder <= 1.5x); peak RSS (VmHWM) of each. `--only-record` runs just this stage.
2. import: that bag into each database (ros_mongo_bag's import) against the same server's raw
   bulk-insert rate for the same payloads (msgs/s, MB/s, ratio; target >= 0.9). `--bag FILE
   --only-import` runs just this stage on a bag kept by an earlier run (`--keep`).
3. replay: ros_mongo_retriever against `rosbag play` of the same data: p50/p99 of the inter-message
   gap error |received gap - recorded gap| per message pair (target: no worse than rosbag play).
   `--bag FILE --only-replay` imports the bag into the first backend and runs just this stage.
4. fault run (CouchDB through ros_harness.fault_proxy, a real proxy process in front of the real
   server): the same load while the proxy answers 30 s of 401 (wrong password), then 30 s of 500
   timeout, then recovers: messages lost (target 0), seconds from recovery until the spool is
   drained, peak memory (VmHWM) of the recorder. `--only-fault` runs just this stage
   (`--fault-seconds` sets each fault's length; quick: 5 s).

Figures are printed, written to artifacts/bench/ros_mongo.json, plots to artifacts/bench/ros_mongo_*.png.
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
PUBLISHER = ROOT / "src" / "ros_mongo" / "scripts" / "ros_mongo_bench_publisher"
sys.path.insert(0, str(Path(__file__).resolve().parent))

from ros_mongo_bench_lib import (  # noqa: E402 - after the path set-up
    BACKENDS,
    TOPICS,
    Arrivals,
    CpuWatch,
    RecorderWatch,
    bag_counts,
    gap_errors,
    peak_rss_mb,
    plot_results,
    raw_bulk_rate,
    recorded_times,
    start_servers,
    subscribers_ready,
)

from ros_harness import FaultProxy, ManagedProcess, RosCore, RosLaunch, wait_until  # noqa: E402
from ros_mongo import open_store  # noqa: E402
from ros_mongo.bagio import import_bag  # noqa: E402


def say(text=""):
    print(text, flush=True)


def bench_record(core, server, work, duration, backend):
    """The recorder and rosbag record on the same publishers at the same time, with the CPU
    seconds and peak memory of the recorder, of the database server it writes to and of rosbag
    record (see `_cpu_figures`)."""
    url = server.database_url("bench")
    bag = work / f"record_{backend}.bag"
    logs = work / "logs"
    recorder = RosLaunch.node("ros_mongo", "ros_mongo_server", master_uri=core.uri, log_dir=logs,
                              env=core.env(), params={
                                  "db_url": url, "topics": list(TOPICS), "session_id": f"bench_{backend}",
                                  "spool_path": str(work / f"{backend}.spool"), "diagnostics_period": 0.5,
                                  "shutdown_timeout": 120.0}).start()
    rosbag = ManagedProcess(["rosbag", "record", "-O", str(bag), *TOPICS], name="rosbag record",
                            log_path=logs / f"rosbag_record_{backend}.log", env=core.env()).start()
    watch = RecorderWatch()
    wait_until(lambda: subscribers_ready(core.uri, TOPICS, 2), 60, what="recorder and rosbag subscribed")
    cpu = CpuWatch()
    cpu.add("recorder", recorder.node_pid("/ros_mongo_server"))
    cpu.add("store", server.process.pid)
    cpu.add("rosbag", rosbag.pid)
    cpu.mark("start")
    publisher = subprocess.run([sys.executable, str(PUBLISHER),
                                "--duration", str(duration), "--wait-subscribers", "2"],
                               capture_output=True, text=True, env=core.env(), timeout=duration + 120)
    if publisher.returncode != 0:
        raise RuntimeError(f"publisher failed: {publisher.stderr[-2000:]}")
    published = json.loads(publisher.stdout.strip().splitlines()[-1])
    at_end = dict(watch.values)
    ended = time.monotonic()
    total = sum(published["published"].values())
    wait_until(lambda: watch.count("stored") + watch.count("dropped") >= watch.count("received") > 0
               and watch.count("spool_pending") == 0 and watch.count("queued") == 0
               and watch.count("received") >= total * 0.5, 600, what="recorder caught up")
    drain = time.monotonic() - ended
    recorder.stop(timeout=150)
    os.killpg(rosbag.pid, signal.SIGINT)  # the wrapper and its `record` child: the bag gets its index
    wait_until(lambda: bag.exists() and not Path(str(bag) + ".active").exists(), 120, interval=0.2,
               what="rosbag record to close the bag")
    rosbag.stop(timeout=10)
    watch.close()
    cpu.close()
    with open_store(url) as store:
        stored = {t: store.count_messages(topic=t, session_id=f"bench_{backend}") for t in TOPICS}
    in_bag = bag_counts(bag)
    seconds = published["seconds"]
    result = {"published": published["published"], "seconds": seconds,
              "recorder": _rates(stored, published["published"], seconds),
              "rosbag": _rates(in_bag, published["published"], seconds),
              "recorder_stored_while_publishing": watch.count_at(at_end, "stored"),
              "recorder_drain_seconds_after_publishing": drain, "bag": str(bag),
              "timeline": watch.timeline}
    rosbag_rate = max(result["rosbag"]["stored_per_s"], 1e-9)
    result["ratio_stored_per_s"] = result["recorder"]["stored_per_s"] / rosbag_rate
    # what reached the database while publishing, and the rate until everything was stored
    result["recorder_realtime_per_s"] = result["recorder_stored_while_publishing"] / seconds
    result["recorder_sustained_per_s"] = result["recorder"]["stored_total"] / (seconds + drain)
    result["ratio_sustained"] = result["recorder_sustained_per_s"] / rosbag_rate
    result["megabytes"] = bag.stat().st_size / 1e6
    result["recorder_spooled"] = watch.count_at(watch.values, "spooled")
    result["cpu"] = _cpu_figures(cpu, result["megabytes"])
    return result


def _cpu_figures(cpu, megabytes):
    """CPU seconds (user + system) from the start of publishing until each process exited (the
    recorder, rosbag) or the recorder exited (the database server, which stays up), total and per
    MB published, as a multiple of rosbag record's `record` process; peak RSS of each."""
    seconds = {"recorder": cpu.cpu("recorder", "start"), "store": cpu.cpu("store", "start"),
               "rosbag_record": cpu.cpu("rosbag", "start", command="record"),
               "rosbag_all": cpu.cpu("rosbag", "start")}
    seconds["recorder_and_store"] = seconds["recorder"] + seconds["store"]
    rosbag = max(seconds["rosbag_record"], 1e-9)
    return {"seconds": seconds, "per_mb": {k: v / megabytes for k, v in seconds.items()},
            "x_rosbag_record": {k: v / rosbag for k, v in seconds.items()},
            "peak_rss_mb": {"recorder": cpu.peak_rss_mb("recorder"), "store": cpu.peak_rss_mb("store"),
                            "rosbag_record": cpu.peak_rss_mb("rosbag", command="record")}}


def bench_fault(core, server, work, fault_seconds, settle=5.0):
    """The recording load through the fault proxy: `fault_seconds` of 401, then of 500 timeout."""
    logs = work / "logs"
    proxy = FaultProxy(server.url, logs).start()
    url = proxy.database_url("bench_fault")
    name = "fault_recorder"
    recorder = RosLaunch.node("ros_mongo", "ros_mongo_server", name=name, master_uri=core.uri, log_dir=logs,
                              env=core.env(), params={
                                  "db_url": url, "topics": list(TOPICS), "session_id": "bench_fault",
                                  "spool_path": str(work / "fault.spool"), "diagnostics_period": 0.5,
                                  "shutdown_timeout": 120.0}).start()
    watch = RecorderWatch()
    try:
        wait_until(lambda: subscribers_ready(core.uri, TOPICS, 1), 60, what="recorder subscribed")
        pid = recorder.node_pid(f"/{name}")
        duration = settle + 2 * fault_seconds + settle
        publisher = subprocess.Popen([sys.executable, str(PUBLISHER), "--duration", str(duration),
                                      "--wait-subscribers", "1"], stdout=subprocess.PIPE, text=True,
                                     env=core.env())
        schedule = [(settle, {"auth": "wrong_password"}, "401 wrong password"),
                    (settle + fault_seconds, {"timeout": "writes"}, "500 timeout"),
                    (settle + 2 * fault_seconds, {}, "recovered")]
        started, peak_pending, recovered_at = time.monotonic(), 0, None
        for at, faults, what in schedule:
            while time.monotonic() - started < at:
                peak_pending = max(peak_pending, watch.count("spool_pending"))
                time.sleep(0.2)
            proxy.set(**faults)
            say(f"  t={time.monotonic() - started:5.1f} s: {what} (stored {watch.count('stored')}, "
                f"spool_pending {watch.count('spool_pending')})")
            recovered_at = time.monotonic()
        out, _ = publisher.communicate(timeout=duration + 300)
        published = json.loads(out.strip().splitlines()[-1])
        total = sum(published["published"].values())
        wait_until(lambda: watch.count("received") >= total * 0.5 and watch.count("spool_pending") == 0
                   and watch.count("queued") == 0
                   and watch.count("stored") + watch.count("dropped") + watch.count("rejected")
                   >= watch.count("received"), 900, interval=0.2, what="the spool drained")
        drained = time.monotonic() - recovered_at
        peak_mb = peak_rss_mb(pid)
        final = dict(watch.values)
        answered = proxy.state()["answered"]
    finally:
        recorder.stop(timeout=150)
        watch.close()
        proxy.stop()
    with open_store(server.database_url("bench_fault")) as store:
        stored = {t: store.count_messages(topic=t, session_id="bench_fault") for t in TOPICS}
    return {"fault_seconds": fault_seconds, "published": published["published"],
            "stored": stored, "lost": {t: published["published"][t] - stored[t] for t in TOPICS},
            "lost_total": sum(published["published"][t] - stored[t] for t in TOPICS),
            "drain_seconds_after_recovery": drained, "peak_rss_mb": peak_mb,
            "peak_spool_pending": peak_pending,
            "counts": {k: final.get(k) for k in ("received", "stored", "dropped", "rejected", "quarantined",
                                                 "spooled", "writer_restarts")},
            "answered_by_proxy": answered}


def _rates(stored, published, seconds):
    return {"stored": stored, "stored_total": sum(stored.values()),
            "stored_per_s": sum(stored.values()) / seconds,
            "drops": {t: published[t] - stored.get(t, 0) for t in published},
            "drops_total": sum(published[t] - stored.get(t, 0) for t in published)}


def bench_import(bag, urls, raw_rate=True):
    """The bag imported into each database and, unless not `raw_rate`, the same server's raw
    bulk-insert rate for the same payloads, measured on fresh databases just before and just
    after the import and averaged (seconds per message): a server still compacting what the
    previous stages wrote is slower for whichever comes first."""
    if raw_rate:  # the import as the ros_mongo_bag command line runs it (not for --only-replay, so
        # the replay's measuring subscriber is the same in runs of versions with and without it)
        try:
            from ros_mongo.allocator import keep_freed_memory
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
    times; gap errors per topic pooled over the runs, and the median of the runs' p99."""
    recorded = recorded_times(bag)
    runs = {"rosbag_play": [], "ros_mongo_retriever": []}
    for run in range(repeats):
        say(f"  replay run {run + 1}/{repeats}")
        runs["rosbag_play"].append(_play_rosbag(core, bag, work))
        runs["ros_mongo_retriever"].append(_play_retriever(core, url, work, extra, recorded))
    results = {}
    for who, arrivals in runs.items():
        results[who] = gap_errors(arrivals, recorded)
        results[who]["p99_ms_per_run"] = [gap_errors(a, recorded)["all"]["p99_ms"] for a in arrivals]
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


def report(results):
    say("\n== ros_mongo benchmark ==")
    for backend, rec in results.get("record", {}).items():
        say(f"record ({backend}, {rec['seconds']:.1f} s; published {rec['published']}):")
        for who in ("recorder", "rosbag"):
            r = rec[who]
            say(f"  {who:9s} stored {r['stored_total']:6d} msgs = {r['stored_per_s']:7.1f} msgs/s, "
                f"drops {r['drops_total']} {r['drops']}")
        say(f"  ratio recorder/rosbag (messages stored per s of publishing): {rec['ratio_stored_per_s']:.3f}")
        say(f"  recorder in time: {rec['recorder_stored_while_publishing']} stored when publishing ended "
            f"({rec['recorder_realtime_per_s']:.0f} msgs/s), all stored "
            f"{rec['recorder_drain_seconds_after_publishing']:.1f} s later: sustained "
            f"{rec['recorder_sustained_per_s']:.0f} msgs/s = {rec['ratio_sustained']:.2f} x rosbag "
            f"({rec['megabytes']:.0f} MB published; {rec['recorder_spooled']} went through the spool)")
        figures = rec["cpu"]
        say("  CPU seconds from the start of publishing (user+system; x rosbag record's record process), "
            "peak RSS:")
        for key, who in (("rosbag_record", "rosbag record (record)"), ("rosbag_all", "rosbag record (all)"),
                         ("recorder", "ros_mongo_server"), ("store", f"{backend} server"),
                         ("recorder_and_store", "recorder + server")):
            rss = figures["peak_rss_mb"].get(key)
            per_mb = figures["per_mb"][key] * 1000
            say(f"    {who:24s} {figures['seconds'][key]:6.2f} s = {per_mb:6.2f} ms/MB "
                f"= {figures['x_rosbag_record'][key]:5.2f} x" + (f", peak RSS {rss:.0f} MB" if rss else ""))
    for backend, imp in results.get("import", {}).items():
        if "raw_msgs_per_s" not in imp:
            say(f"import ({backend}, {imp['messages']} msgs, {imp['megabytes']:.0f} MB): "
                f"{imp['import_msgs_per_s']:.0f} msgs/s, {imp['import_mb_per_s']:.1f} MB/s (for the replay)")
            continue
        say(f"import ({backend}, {imp['messages']} msgs, {imp['megabytes']:.0f} MB): "
            f"{imp['import_msgs_per_s']:.0f} msgs/s, {imp['import_mb_per_s']:.1f} MB/s; raw bulk insert "
            f"{imp['raw_msgs_per_s']:.0f} msgs/s, {imp['raw_mb_per_s']:.1f} MB/s (before / after the "
            f"import {imp['raw_before_msgs_per_s']:.0f} / {imp['raw_after_msgs_per_s']:.0f}); ratio "
            f"{imp['ratio_msgs']:.2f} (msgs) {imp['ratio_mb']:.2f} (MB)")
    fault = results.get("fault")
    if fault:
        seconds = fault["fault_seconds"]
        say(f"fault run (CouchDB; {seconds:.0f} s of 401 then {seconds:.0f} s of 500 timeout): published "
            f"{sum(fault['published'].values())}, lost {fault['lost_total']} "
            f"{fault['lost']} (target 0); spool drained {fault['drain_seconds_after_recovery']:.1f} s after "
            f"recovery (peak {fault['peak_spool_pending']} pending); recorder peak RSS "
            f"{fault['peak_rss_mb']:.0f} MB; counts {fault['counts']}")
    for who, rep in results.get("replay", {}).items():
        total = rep["all"]
        per_run = ", ".join(f"{v:.2f}" for v in rep["p99_ms_per_run"])
        say(f"replay {who:20s} gap error p50 {total['p50_ms']:.3f} ms, p99 {total['p99_ms']:.3f} ms "
            f"(pooled over {len(rep['p99_ms_per_run'])} runs; p99 per run {per_run} ms), "
            f"received {total['received']}/{total['expected']}")
        for topic, value in rep.items():
            if topic.startswith("/"):
                say(f"    {topic:24s} p50 {value['p50_ms']:.3f} ms, p99 {value['p99_ms']:.3f} ms, "
                    f"received {value['received']}/{value['expected']}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run: 4 s of publishing, CouchDB only")
    parser.add_argument("--duration", type=float, help="seconds of publishing (default 20, quick 4)")
    parser.add_argument("--backends", nargs="*", choices=BACKENDS, help="default: both (quick: couchdb)")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "bench")
    parser.add_argument("--keep", action="store_true", help="keep the work folder (bags, databases)")
    parser.add_argument("--bag", type=Path, help="skip recording: import and replay this bag (recorded by "
                        "an earlier run with --keep)")
    parser.add_argument("--replay-repeats", type=int, default=3,
                        help="replays of each kind, alternating (default 3)")
    parser.add_argument("--retriever-param", nargs="*", default=[], metavar="KEY=YAML",
                        help="extra ros_mongo_retriever parameters for the replay stage")
    parser.add_argument("--fault-seconds", type=float, help="length of each injected fault (default 30, "
                        "quick 5)")
    parser.add_argument("--only-fault", action="store_true", help="run only the fault run")
    parser.add_argument("--only-record", action="store_true", help="run only the record stage (with its "
                        "CPU figures)")
    parser.add_argument("--only-import", action="store_true", help="with --bag: run only the import "
                        "stage (import and raw bulk rate, each backend)")
    parser.add_argument("--only-replay", action="store_true", help="with --bag: import it into the first "
                        "backend (no raw bulk rate), then run only the replay stage")
    args = parser.parse_args(argv)
    if (args.only_import or args.only_replay) and args.bag is None:
        parser.error("--only-import and --only-replay need --bag (a bag kept by an earlier run with --keep, "
                     "e.g. artifacts/bench/ros_mongo_work/record_couchdb.bag)")
    duration = args.duration or (4.0 if args.quick else 20.0)
    backends = args.backends or (["couchdb"] if args.quick else list(BACKENDS))
    fault_seconds = args.fault_seconds or (5.0 if args.quick else 30.0)
    if args.only_fault:
        backends = ["couchdb"]
    if args.only_replay:
        backends = backends[:1]
    args.output.mkdir(parents=True, exist_ok=True)
    work = args.output / "ros_mongo_work"
    if args.bag is not None:
        args.bag = args.bag.resolve()
        work = args.output / "ros_mongo_work_replay"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    core = RosCore(log_dir=work / "logs").start()
    os.environ.update(core.env())
    servers = start_servers(work, backends)
    import rospy

    rospy.init_node("ros_mongo_bench", anonymous=True, disable_signals=True)
    load = os.getloadavg()
    results = {"duration": duration, "load_before": load, "cpus": os.cpu_count(), "record": {}}
    try:
        if args.only_fault or (args.bag is None and not args.only_record):
            say(f"fault run: {fault_seconds:.0f} s of 401, {fault_seconds:.0f} s of 500 timeout ...")
            results["fault"] = bench_fault(core, servers["couchdb"], work, fault_seconds) \
                if "couchdb" in servers else None
        if args.only_fault:
            return _finish(args, results, work, load, servers, core, name="ros_mongo_fault.json")
        for backend in backends if args.bag is None else []:
            say(f"record: {backend}, {duration:.0f} s of publishing ...")
            results["record"][backend] = bench_record(core, servers[backend], work, duration, backend)
        if args.only_record:
            return _finish(args, results, work, load, servers, core, name="ros_mongo_record.json")
        bag = args.bag or Path(results["record"][backends[0]]["bag"])
        say("import ...")
        targets = backends[:1] if args.only_replay else backends
        results["import"] = bench_import(bag, {b: servers[b].database_url("bench") for b in targets},
                                         raw_rate=not args.only_replay)
        if args.only_import:
            return _finish(args, results, work, load, servers, core, name="ros_mongo_import.json")
        say("replay ...")
        extra = {k: yaml.safe_load(v) for k, v in (p.split("=", 1) for p in args.retriever_param)}
        results["replay"] = bench_replay(core, bag, servers[backends[0]].database_url("bench"), work, extra,
                                         args.replay_repeats)
    except BaseException:
        _stop(servers, core, results)
        raise
    return _finish(args, results, work, load, servers, core)


def _stop(servers, core, results):
    import rospy

    rospy.signal_shutdown("bench finished")
    for server in servers.values():
        server.stop()
    core.stop()
    results["load_after"] = os.getloadavg()


def _finish(args, results, work, load, servers, core, name="ros_mongo.json"):
    _stop(servers, core, results)
    report(results)
    (args.output / name).write_text(json.dumps(results, indent=1, default=str))
    if name == "ros_mongo.json":
        plot_results(results, args.output)
    say(f"\nload average before {load[0]:.1f}, after {results['load_after'][0]:.1f} ({os.cpu_count()} CPUs); "
        f"figures in {args.output / name}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
