"""Object layers: the layer server learns where the generated building's objects and places are
from simulated noisy detections, and answers questions about them (checked against the truth)."""
import math
from dataclasses import replace

import numpy as np
import rospy
from geometry_msgs.msg import Point

from igmm_layers.msg import ClusterSet
from igmm_layers.sim.metrics import match_scores, ospa
from igmm_layers.srv import (
    AlternateObject,
    CountObjects,
    LayerInfo,
    LoadClusters,
    LocateObjects,
    LookupObject,
    ObjectPairLikelihood,
    SaveClusters,
)
from robot_common.maps import OCCUPIED
from robot_demo import waits
from robot_demo.waits import wait_until
from robot_sim.detections import building_detections
from robot_sim.params import ObjectDetectionSimParams
from ros_harness import master_graph

TITLE = "Object layers: where things are, learnt from noisy detections (igmm_layers)"
SEED, RANDOM_SEED = 0, 1


def service(name, srv):
    return rospy.ServiceProxy(f"/igmm_layers/{name}", srv)


def run(demo) -> None:
    # the same detections object_detection_sim publishes (its launch file's parameters, the seeds
    # given below): to know when all arrived, and the truth to score the layers against
    config = replace(demo.sim_config(ObjectDetectionSimParams, "object_detection_sim.yaml"), seed=SEED,
                     random_seed=RANDOM_SEED)
    building, dets = building_detections(config)
    sightings = config.place_detections * len(building.labels)
    expected = len(dets) + sightings
    has_map = any(topic == "/map" for topic, _ in master_graph(demo.core.uri).getPublishedTopics("/"))
    launch = demo.launch(demo.workspace_launch("object_layers_sim.launch"), seed=SEED,
                         random_seed=RANDOM_SEED, db_url=demo.db_url, with_map=not has_map)
    waits.services(launch, ["/igmm_layers/layer_info", "/igmm_layers/load_clusters"], 120)
    info = service("layer_info", LayerInfo)
    settled = wait_until(lambda: (lambda i: i if i.received >= expected and
                                  i.received == i.applied + i.dropped else None)(info()), 180,
                         what="the layer server to take in every simulated detection")
    print(f"  simulated: {len(building.objects)} objects of {len({o.class_name for o in building.objects})} "
          f"classes, {len(dets)} detections ({np.sum(dets.truth < 0)} clutter, noise {config.noise_std} m, "
          f"random order) + {sightings} sightings of {len(building.labels)} places")
    print(f"  layer server: {settled.applied} observations learnt, {settled.dropped} dropped; "
          + ", ".join(f"{r}/{k}: {c} clusters ({n} components)" for r, k, c, n in
                      zip(settled.region_ids, settled.layers, settled.clusters, settled.components)))
    found = service("locate_objects", LocateObjects)(class_name="any", region_id="", layer="objects").clusters
    report_quality(building, found)
    ask_questions(building)
    persist()
    plot(demo, building, found)


def report_quality(building, clusters) -> None:
    matched, total_found, osp = 0, 0, []
    for name in sorted({o.class_name for o in building.objects}):
        truth = np.array([(o.x, o.y) for o in building.objects_of(name)])
        means = np.array([(c.mean.x, c.mean.y) for c in clusters if c.class_name == name]).reshape(-1, 2)
        scores = match_scores(means, truth, radius=0.5)
        matched += scores["matched"]
        total_found += len(means)
        osp.append(ospa(means, truth, cutoff=1.0))
    n_true = len(building.objects)
    print(f"  vs truth: {total_found} clusters for {n_true} objects; within 0.5 m: precision "
          f"{matched / max(total_found, 1):.2f}, recall {matched / n_true:.2f}; mean OSPA per class "
          f"{np.mean(osp):.3f} m (cut-off 1 m)")


def ask_questions(building) -> None:
    kitchen = next(a for a in building.rooms if a.label == "kitchen")
    sinks = np.array([(o.x, o.y) for o in building.objects_of("sink")])
    answer = service("lookup_object", LookupObject)(class_name="sink", region_id="", layer="objects",
                                                    mode="closest", point=Point(*kitchen.centre, 0.0))
    true_sink = sinks[np.argmin(np.linalg.norm(sinks - kitchen.centre, axis=1))]
    found = (answer.cluster.mean.x, answer.cluster.mean.y)
    print(f"  lookup closest sink to the kitchen centre {tuple(round(v, 1) for v in kitchen.centre)}: "
          f"({found[0]:.2f}, {found[1]:.2f}); true ({true_sink[0]:.2f}, {true_sink[1]:.2f}), error "
          f"{math.hypot(found[0] - true_sink[0], found[1] - true_sink[1]):.2f} m")
    likely = service("lookup_object", LookupObject)(class_name="furniture", region_id="", layer="",
                                                    mode="most_likely", point=Point())
    print(f"  lookup most likely 'furniture' (group of chair, table, desk, couch): {likely.message}")
    pair = service("pair_likelihood", ObjectPairLikelihood)
    for method in ("overlap", "distance_weighted"):
        same = pair(class_a="microwave", class_b="fridge", region_id="", layer="", max_distance=0.0,
                    method=method)
        other = pair(class_a="microwave", class_b="whiteboard", region_id="", layer="", max_distance=0.0,
                     method=method)
        print(f"  pair likelihood ({method}): microwave near fridge {same.likelihood:.3g} "
              f"vs near whiteboard {other.likelihood:.3g} (truth: fridges share the kitchen)")
    alternate = service("alternate_object", AlternateObject)(class_name="microwave", region_id="", layer="",
                                                             max_distance=0.0, method="", candidates=[])
    kitchen_classes = sorted({o.class_name for o in building.objects if o.area == kitchen.name}
                             - {"microwave"})
    print(f"  alternate object for 'microwave': {alternate.class_name} "
          f"(ranked {', '.join(alternate.ranked_classes[:4])}); truth: the kitchen also has "
          f"{', '.join(kitchen_classes)}")
    room = next(a for a in building.rooms if a.label.startswith("classroom"))
    now = rospy.Time.now()
    count = service("count_objects", CountObjects)(class_names=["chair", "furniture"], region_id="", layer="",
                                                   start=now - rospy.Duration(120), end=now,
                                                   center=Point(*room.centre, 0.0), radius=3.5)
    true_chairs = sum(1 for o in building.objects_of("chair") if math.hypot(o.x - room.centre[0],
                                                                            o.y - room.centre[1]) <= 3.5)
    print(f"  count objects seen in the last 2 min within 3.5 m of {room.label}: {count.message} "
          f"(true chairs there: {true_chairs})")
    locate = service("locate_objects", LocateObjects)
    places = locate(class_name="any", region_id="", layer="regions").clusters
    names = sorted(c.class_name for c in places)
    print(f"  regions layer: {len(places)} labelled places learnt ({', '.join(names[:5])}, ...) "
          f"of {len(building.labels)}")


def persist() -> None:
    saved = service("save_clusters", SaveClusters)(region_id="", layer="")
    print(f"  save_clusters: {saved.message} (database id {saved.id})")
    forget = rospy.Publisher("/igmm_layers/restore", ClusterSet, queue_size=1, latch=True)
    wipe = ClusterSet(layers=["default/objects", "default/regions"])
    wipe.header.stamp = rospy.Time.now()
    forget.publish(wipe)
    locate = service("locate_objects", LocateObjects)
    wait_until(lambda: not locate(class_name="any", region_id="", layer="").clusters, 60,
               what="the layers to be forgotten")
    forget.unregister()
    loaded = service("load_clusters", LoadClusters)(timestamp="")
    back = locate(class_name="any", region_id="", layer="").clusters
    print(f"  forgot everything, then load_clusters (latest): {loaded.message}; "
          f"{len(back)} object clusters answer again")


def plot(demo, building, clusters) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    from igmm_layers.visual import ellipse

    grid = building.grid
    fig, ax = plt.subplots(figsize=(13, 6.5))
    extent = (0, grid.width * grid.resolution, 0, grid.height * grid.resolution)
    ax.imshow(grid.cells == OCCUPIED, cmap="Greys", origin="lower", extent=extent, alpha=0.8)
    colours = {}
    for cluster in clusters:
        major, minor, yaw = ellipse(np.array(cluster.covariance).reshape(3, 3))
        colour = colours.setdefault(cluster.class_name, plt.cm.tab20(len(colours) % 20))
        ax.add_patch(Ellipse((cluster.mean.x, cluster.mean.y), major, minor, angle=math.degrees(yaw),
                             color=colour, alpha=0.6))
        ax.text(cluster.mean.x, cluster.mean.y + 0.25, cluster.class_name, fontsize=6, ha="center")
    ax.plot([o.x for o in building.objects], [o.y for o in building.objects], "k+", markersize=7,
            label="true object positions")
    ax.set_title("igmm_layers: learnt object clusters (2-sigma ellipses) over the generated building")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    path = demo.output / "object_layers.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"  plot: {path}")
