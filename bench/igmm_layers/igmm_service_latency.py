#!/usr/bin/env python3
"""Latency of the layer server's services with 10,000 clusters, through ROS (real roscore and
node), against the same handlers called in-process (no ROS transport).

    python bench/igmm_layers/igmm_service_latency.py [--quick] [--calls N] [--clusters N]

The clusters (20 classes, 500 each by default, one 200 m x 200 m region) are published as one
ClusterSet on /igmm_layers/restore, the way load_clusters restores a saved set. Each service is
called with random arguments by a plain rospy.ServiceProxy (a new connection per call, as most
clients do) and by a persistent one. Reports p50/p99/max in milliseconds.
Writes artifacts/bench/igmm_service_latency.json and igmm_service_latency.png.
"""
import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rospy
import yaml
from geometry_msgs.msg import Point

from igmm_layers.msg import ClusterSet, ObjectCluster
from igmm_layers.params import LayerServerConfig
from igmm_layers.ros_convert import apply_cluster_set
from igmm_layers.ros_layer_server import LayerServer
from igmm_layers.ros_services import LayerServices
from igmm_layers.srv import (
    AlternateObject,
    CountObjects,
    LayerInfo,
    LocateObjects,
    LookupObject,
    ObjectPairLikelihood,
)
from ros_harness import RosCore, RosLaunch, wait_until

OUT_DIR = Path(__file__).resolve().parents[2] / "artifacts" / "bench"
CONFIG = Path(__file__).resolve().parents[2] / "src" / "igmm_layers" / "config" / "igmm_layers.yaml"
REGION = "bench"


def cluster_set(n_clusters: int, n_classes: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    msg = ClusterSet(layers=[f"{REGION}/objects"])
    msg.header.stamp = rospy.Time.now()
    now = time.time()
    for i in range(n_clusters):
        sx, sy = rng.uniform(0.05, 0.4, 2)
        cov = [sx ** 2, 0.0, 0.0, 0.0, sy ** 2, 0.0, 0.0, 0.0, 0.0]
        cluster = ObjectCluster(class_name=f"class_{i % n_classes:02d}", region_id=REGION, layer="objects",
                                covariance=cov, support=float(rng.uniform(3, 50)), observations=100)
        cluster.mean.x, cluster.mean.y = rng.uniform(0, 200, 2)
        msg.clusters.append(cluster)
        msg.time_counts.append(3)
        msg.observation_times += [rospy.Time.from_sec(now - rng.uniform(0, 3600)) for _ in range(3)]
    return msg


def requests(n_classes: int, calls: int, seed: int = 1):
    """(service, srv type, list of request kwargs) with random arguments."""

    rng = np.random.default_rng(seed)

    def cls():
        return f"class_{rng.integers(n_classes):02d}"

    def point():
        return Point(*rng.uniform(0, 200, 2), 0.0)
    now = time.time()
    return {
        "lookup most_likely": ("lookup_object", LookupObject,
                               [dict(class_name=cls(), region_id=REGION, mode="most_likely")
                                for _ in range(calls)]),
        "lookup closest": ("lookup_object", LookupObject,
                           [dict(class_name=cls(), region_id=REGION, mode="closest", point=point())
                            for _ in range(calls)]),
        "pair overlap": ("pair_likelihood", ObjectPairLikelihood,
                         [dict(class_a=cls(), class_b=cls(), region_id=REGION, method="overlap")
                          for _ in range(calls)]),
        "pair distance_weighted": ("pair_likelihood", ObjectPairLikelihood,
                                   [dict(class_a=cls(), class_b=cls(), region_id=REGION,
                                         method="distance_weighted") for _ in range(calls)]),
        "alternate object": ("alternate_object", AlternateObject,
                             [dict(class_name=cls(), region_id=REGION) for _ in range(max(calls // 5, 10))]),
        "count objects": ("count_objects", CountObjects,
                          [dict(class_names=[cls(), cls()], region_id=REGION, center=point(), radius=20.0,
                                start=rospy.Time.from_sec(now - 1800), end=rospy.Time.from_sec(now))
                           for _ in range(calls)]),
        "locate one class (500)": ("locate_objects", LocateObjects,
                                   [dict(class_name=cls(), region_id=REGION)
                                    for _ in range(max(calls // 5, 10))]),
        "locate any (all)": ("locate_objects", LocateObjects,
                             [dict(class_name="any", region_id=REGION) for _ in range(max(calls // 50, 5))]),
    }


def percentiles(times):
    return {"calls": len(times), "p50_ms": float(np.percentile(times, 50)),
            "p99_ms": float(np.percentile(times, 99)), "max_ms": float(np.max(times))}


def timed(call, kwargs_list):
    call(**kwargs_list[0])  # warm-up (lazy imports, first connection), not counted
    times = []
    for kwargs in kwargs_list:
        start = time.perf_counter()
        answer = call(**kwargs)
        times.append(1000.0 * (time.perf_counter() - start))
        if not answer.success:
            raise RuntimeError(f"{kwargs}: {answer.message}")
    return times


def in_process(msg, plan):
    """The same handlers without ROS transport: a LayerServer that is never set up."""
    server = LayerServer(LayerServerConfig.from_params(yaml.safe_load(CONFIG.read_text())))
    apply_cluster_set(server.layers, msg)
    services = LayerServices(server)
    handlers = {"lookup_object": services.lookup, "pair_likelihood": services.pair,
                "alternate_object": services.alternate, "count_objects": services.count,
                "locate_objects": services.locate}
    results = {}
    for title, (name, srv, kwargs_list) in plan.items():
        handler = services._guard(srv, handlers[name], True)

        def call(handler=handler, srv=srv, **kwargs):
            return handler(srv._request_class(**kwargs))
        results[title] = percentiles(timed(call, kwargs_list))
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="50 calls per service")
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--clusters", type=int, default=10000)
    parser.add_argument("--classes", type=int, default=20)
    args = parser.parse_args()
    calls = 50 if args.quick else args.calls
    print(f"load average {os.getloadavg()[0]:.2f}; {args.clusters} clusters of {args.classes} classes")
    with tempfile.TemporaryDirectory(prefix="igmm_latency_") as tmp:
        core = RosCore(log_dir=Path(tmp)).start()
        os.environ.update(core.env())
        try:
            return run(core, Path(tmp), args, calls)
        finally:
            core.stop()


def run(core, tmp: Path, args, calls: int) -> int:
    rospy.init_node("igmm_latency_bench", anonymous=True, disable_signals=True)
    params = yaml.safe_load(CONFIG.read_text())
    server = RosLaunch.node("igmm_layers", "igmm_layers", name="igmm_layers", master_uri=core.uri,
                            log_dir=tmp, env=core.env(), params=params).start()
    try:
        server.wait_for_services(["/igmm_layers/layer_info"], timeout=60)
        msg = cluster_set(args.clusters, args.classes)
        start = time.perf_counter()
        restore = rospy.Publisher("/igmm_layers/restore", ClusterSet, queue_size=1, latch=True)
        restore.publish(msg)
        info = rospy.ServiceProxy("/igmm_layers/layer_info", LayerInfo)
        wait_until(lambda: sum(info().clusters) == args.clusters, 120, what="the clusters to be restored")
        print(f"restored {args.clusters} clusters through /igmm_layers/restore in "
              f"{time.perf_counter() - start:.2f} s")
        plan = requests(args.classes, calls)
        results = {"ros_new_connection": {}, "ros_persistent": {}}
        for title, (name, srv, kwargs_list) in plan.items():
            proxy = rospy.ServiceProxy(f"/igmm_layers/{name}", srv)
            results["ros_new_connection"][title] = percentiles(timed(proxy, kwargs_list))
            persistent = rospy.ServiceProxy(f"/igmm_layers/{name}", srv, persistent=True)
            try:
                results["ros_persistent"][title] = percentiles(timed(persistent, kwargs_list))
            finally:
                persistent.close()
    finally:
        server.stop()
    results["in_process"] = in_process(msg, plan)
    print(f"\n{'service':26s} {'calls':>5s} {'ROS p50':>8s} {'ROS p99':>8s} {'persist p99':>11s} "
          f"{'in-proc p99':>11s}   (ms)")
    for title in plan:
        ros, persistent, local = (results[k][title]
                                  for k in ("ros_new_connection", "ros_persistent", "in_process"))
        print(f"{title:26s} {ros['calls']:5d} {ros['p50_ms']:8.2f} {ros['p99_ms']:8.2f} "
              f"{persistent['p99_ms']:11.2f} {local['p99_ms']:11.2f}")
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    (OUT_DIR / "igmm_service_latency.json").write_text(json.dumps(
        {"clusters": args.clusters, "classes": args.classes, "load_average": os.getloadavg()[0],
         "results": results}, indent=2))
    plot(results, list(plan), OUT_DIR / "igmm_service_latency.png")
    print(f"wrote {OUT_DIR / 'igmm_service_latency.json'} and igmm_service_latency.png")
    return 0


def plot(results, titles, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.27
    for i, (key, label) in enumerate((("ros_new_connection", "ROS, new connection"),
                                      ("ros_persistent", "ROS, persistent"), ("in_process", "in-process"))):
        ax.bar(np.arange(len(titles)) + i * width, [results[key][t]["p99_ms"] for t in titles], width,
               label=label)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(titles)) + width)
    ax.set_xticklabels([t.replace(" ", "\n", 1) for t in titles], fontsize=7)
    ax.set_ylabel("p99 latency (ms)")
    ax.set_title("igmm_layers services with 10,000 clusters")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
