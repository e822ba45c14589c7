"""The layer server node through its real topics and services (real roscore, node, CouchDB)."""
import math
import threading

import numpy as np
import pytest
from geometry_msgs.msg import Point, TransformStamped, Vector3

from igmm_layers.msg import ClusterSet
from igmm_layers.sim.metrics import match_scores
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
from robot_common.msg import ObjectObservation
from robot_sim import generate_building
from robot_sim.detections import building_scene, simulate_detections
from ros_harness import free_port, wait_until

pytestmark = [pytest.mark.ros, pytest.mark.db]
BUILDING = generate_building(0)


def obs(name, x, y, *, region="", frame="map", confidence=1.0, size=(0.0, 0.0, 0.0), stamp=None):
    import rospy

    msg = ObjectObservation(class_name=name, position=Point(x, y, 0.0), confidence=confidence,
                            size=Vector3(*size), region_id=region)
    msg.header.frame_id = frame
    msg.header.stamp = rospy.Time.from_sec(stamp) if stamp is not None else rospy.Time.now()
    return msg


def call(rospy_node, name, srv, **request):
    return rospy_node.ServiceProxy(f"/igmm_layers/{name}", srv)(**request)


def located_in_building(rospy_node):
    return call(rospy_node, "locate_objects", LocateObjects, class_name="any", region_id="building",
                layer="")


@pytest.fixture(scope="module")
def building_learnt(layer_server, observe):
    """The generated building's objects learnt from simulated noisy detections (region "building")."""
    dets = simulate_detections(building_scene(BUILDING), mean_detections=20, noise_std=0.1,
                               clutter_fraction=0.1, extent_spread=True, random_state=4)
    messages = [obs(dets.class_names[i], *dets.positions[i], region="building",
                    size=(*dets.sizes[i], 0.0)) for i in range(len(dets))]
    info = observe(messages)
    assert info.dropped == 0
    return dets


def truth_of(name):
    return np.array([(o.x, o.y) for o in BUILDING.objects_of(name)])


def test_learns_the_building_and_answers_like_the_truth(rospy_node, building_learnt):
    for name in ("chair", "table", "sink"):
        found = call(rospy_node, "locate_objects", LocateObjects, class_name=name, region_id="building",
                     layer="objects")
        assert found.success and {c.class_name for c in found.clusters} == {name}
        means = np.array([(c.mean.x, c.mean.y) for c in found.clusters])
        scores = match_scores(means, truth_of(name), radius=0.5)
        assert scores["precision"] >= 0.9 and scores["recall"] >= 0.9, (name, scores)
    group = call(rospy_node, "locate_objects", LocateObjects, class_name="furniture", region_id="", layer="")
    assert {c.class_name for c in group.clusters} == {"chair", "table", "desk", "couch"}
    kitchen = next(a for a in BUILDING.rooms if a.label == "kitchen")
    answer = call(rospy_node, "lookup_object", LookupObject, class_name="sink", region_id="building",
                  layer="objects", mode="closest", point=Point(*kitchen.centre, 0.0))
    sinks = truth_of("sink")
    nearest = sinks[np.argmin(np.linalg.norm(sinks - kitchen.centre, axis=1))]
    assert answer.success
    assert np.hypot(answer.cluster.mean.x - nearest[0], answer.cluster.mean.y - nearest[1]) < 0.3
    assert answer.distance == pytest.approx(np.hypot(answer.cluster.mean.x - kitchen.centre[0],
                                                     answer.cluster.mean.y - kitchen.centre[1]))
    likely = call(rospy_node, "lookup_object", LookupObject, class_name="chair", region_id="building",
                  layer="", mode="", point=Point())
    assert likely.success and likely.cluster.class_name == "chair"


def test_pair_likelihood_and_alternate_object_follow_the_rooms(rospy_node, building_learnt):
    def pair(a, b, method=""):
        answer = call(rospy_node, "pair_likelihood", ObjectPairLikelihood, class_a=a, class_b=b,
                      region_id="building", layer="objects", max_distance=0.0, method=method)
        assert answer.success, answer.message
        return answer
    for method in ("overlap", "distance_weighted"):
        same_room, other_room = pair("microwave", "fridge", method), pair("microwave", "whiteboard", method)
        assert same_room.method == method and same_room.likelihood > other_room.likelihood
    assert pair("microwave", "fridge").method == "distance_weighted"  # the server's default
    alternate = call(rospy_node, "alternate_object", AlternateObject, class_name="microwave",
                     region_id="building", layer="objects", max_distance=0.0, method="", candidates=[])
    kitchen_classes = {"fridge", "sink", "table"}
    assert alternate.success and alternate.class_name in kitchen_classes
    assert alternate.ranked_classes[0] == alternate.class_name and "microwave" not in alternate.ranked_classes
    assert list(alternate.likelihoods) == sorted(alternate.likelihoods, reverse=True)


def test_count_objects_in_a_time_window_and_radius(rospy_node, observe):
    messages = [obs("cup", 0.01 * k, 0.0, region="timing", stamp=1000.0 + k) for k in range(5)]
    messages += [obs("cup", 10.0 + 0.01 * k, 0.0, region="timing", stamp=2000.0 + k) for k in range(5)]
    messages += [obs("plate", 10.0, 0.5 + 0.01 * k, region="timing", stamp=2000.0 + k) for k in range(4)]
    observe(messages)

    def count(names, start=0.0, end=0.0, center=(0.0, 0.0), radius=0.0):
        import rospy
        answer = call(rospy_node, "count_objects", CountObjects, class_names=names, region_id="timing",
                      layer="objects", start=rospy.Time.from_sec(start), end=rospy.Time.from_sec(end),
                      center=Point(center[0], center[1], 0.0), radius=radius)
        assert answer.success, answer.message
        return dict(zip(answer.class_names, zip(answer.counts, answer.observations)))
    assert count(["cup"]) == {"cup": (2, 10)}
    assert count(["cup", "plate"], start=999.0, end=1010.0) == {"cup": (1, 5), "plate": (0, 0)}
    assert count(["cup"], start=2001.5) == {"cup": (1, 3)}
    assert count([], center=(10.0, 0.0), radius=1.0) == {"cup": (1, 5), "plate": (1, 4)}


def test_per_region_topic_and_tf2_transform_into_the_map(rospy_node, observe, layer_server):
    import rospy
    import tf2_ros

    transform = TransformStamped()
    transform.header.stamp, transform.header.frame_id = rospy.Time.now(), "map"
    transform.child_frame_id = "test_camera"
    transform.transform.translation.x = 100.0
    rotation = transform.transform.rotation
    rotation.z, rotation.w = math.sin(math.pi / 4), math.cos(math.pi / 4)
    broadcaster = tf2_ros.StaticTransformBroadcaster()
    broadcaster.sendTransform(transform)
    rng = np.random.default_rng(0)
    # camera (1, 0) is map (100, 1) after the 90 degree turn; the 0.6 m long axis becomes map y
    messages = [obs("mug", 1.0 + rng.normal(0, 0.02), rng.normal(0, 0.02), frame="test_camera",
                    size=(0.6, 0.0, 0.0)) for _ in range(8)]
    info = observe(messages, topic="/floor_4/objects")
    assert info.dropped == 0
    found = call(rospy_node, "locate_objects", LocateObjects, class_name="mug", region_id="floor_4", layer="")
    assert len(found.clusters) == 1 and found.clusters[0].region_id == "floor_4"
    mug = found.clusters[0]
    assert (mug.mean.x, mug.mean.y) == (pytest.approx(100.0, abs=0.05), pytest.approx(1.0, abs=0.05))
    assert mug.covariance[4] > mug.covariance[0] + 0.02  # widened along map y by the size
    assert "/floor_4/objects" in info.observation_topics


def test_bad_observations_are_dropped_counted_and_harm_nothing(rospy_node, observe, building_learnt):
    before = located_in_building(rospy_node)
    bad = [obs("chair", 1.0, 1.0, region="building", confidence=0.0),
           obs("", 1.0, 1.0, region="building"),
           obs("chair", float("nan"), 1.0, region="building"),
           obs("chair", 1.0, 1.0, region="building", frame="no_such_frame")]
    info = observe(bad)
    assert info.dropped == 4 and "no_such_frame" in info.last_drop_reason
    wrong_region = observe([obs("mug", 100.0, 1.0, region="building")], topic="/floor_4/objects")
    assert wrong_region.dropped == 5 and "on the topic of region 'floor_4'" in wrong_region.last_drop_reason
    after = located_in_building(rospy_node)
    assert [(c.mean.x, c.support) for c in after.clusters] == [(c.mean.x, c.support) for c in before.clusters]


@pytest.mark.parametrize("name,srv,request_fields,message", [
    ("locate_objects", LocateObjects, {"class_name": "spoon"}, "unknown class 'spoon'"),
    ("locate_objects", LocateObjects, {"class_name": "chair", "region_id": "mars"}, "unknown region 'mars'"),
    ("locate_objects", LocateObjects, {"class_name": "chair", "layer": "rooms"}, "unknown layer 'rooms'"),
    ("lookup_object", LookupObject, {"class_name": "chair", "mode": "nearest"}, "unknown mode 'nearest'"),
    ("lookup_object", LookupObject, {"class_name": "couch", "region_id": "floor_4"},
     "no clusters of 'couch'"),
    ("pair_likelihood", ObjectPairLikelihood, {"class_a": "chair", "class_b": "table", "method": "cosine"},
     "unknown method 'cosine'"),
    ("pair_likelihood", ObjectPairLikelihood, {"class_a": "chair", "class_b": "table", "max_distance": -2.0},
     "max_distance must be positive"),
    ("alternate_object", AlternateObject, {"class_name": "spoon"}, "unknown class 'spoon'"),
    ("count_objects", CountObjects, {"class_names": ["chair"], "radius": -1.0}, "radius must be >= 0"),
    ("load_clusters", LoadClusters, {"timestamp": "1999-01-01T00:00:00.000000Z"}, "no saved cluster set"),
])
def test_bad_requests_get_success_false_and_a_clear_message(rospy_node, building_learnt, name, srv,
                                                            request_fields, message):
    answer = call(rospy_node, name, srv, **request_fields)
    assert not answer.success and message in answer.message
    assert call(rospy_node, "layer_info", LayerInfo).success  # the server is still fine


def test_count_window_that_ends_before_it_starts_is_refused(rospy_node, building_learnt):
    import rospy

    answer = call(rospy_node, "count_objects", CountObjects, class_names=["chair"],
                  start=rospy.Time(20), end=rospy.Time(10))
    assert not answer.success and "starts after it ends" in answer.message


def test_markers_are_published_only_to_listeners_and_replace_the_old_ones(rospy_node, building_learnt,
                                                                          observe):
    from visualization_msgs.msg import Marker, MarkerArray

    observe([obs("chair", 3.0, 3.0, region="quiet") for _ in range(5)])  # a layer nobody listens to
    received, lock = [], threading.Lock()

    def keep(msg):
        with lock:
            received.append(msg)
    subscriber = rospy_node.Subscriber("/igmm_layers/markers/building/objects", MarkerArray, keep)
    try:
        first = wait_until(lambda: received and received[0], 90, what="markers")
    finally:
        subscriber.unregister()
    assert first.markers[0].action == Marker.DELETEALL
    located = located_in_building(rospy_node)
    ellipses = [m for m in first.markers if m.type == Marker.CYLINDER]
    labels = [m for m in first.markers if m.type == Marker.TEXT_VIEW_FACING]
    assert len(ellipses) == len(labels) == len(located.clusters)
    assert {m.text for m in labels} == {c.class_name for c in located.clusters}
    for cluster in located.clusters[:5]:
        shape = min(ellipses, key=lambda m: math.hypot(m.pose.position.x - cluster.mean.x,
                                                       m.pose.position.y - cluster.mean.y))
        cov = np.array(cluster.covariance).reshape(3, 3)[:2, :2]
        assert shape.scale.x == pytest.approx(4 * math.sqrt(np.linalg.eigvalsh(cov).max()), rel=1e-6)
        assert shape.scale.y == pytest.approx(4 * math.sqrt(np.linalg.eigvalsh(cov).min()), rel=1e-6)
    colours = {}
    for shape in ellipses:
        label = min(labels, key=lambda m: math.hypot(m.pose.position.x - shape.pose.position.x,
                                                     m.pose.position.y - shape.pose.position.y - 0.3))
        colours.setdefault(label.text, set()).add((shape.color.r, shape.color.g, shape.color.b))
    assert all(len(c) == 1 for c in colours.values()) and len(set().union(*colours.values())) == len(colours)
    # this marker array came from a timer tick after the "quiet" layer changed: nothing built for it
    info = call(rospy_node, "layer_info", LayerInfo)
    updates = {(r, k): n for r, k, n in zip(info.region_ids, info.layers, info.marker_updates)}
    assert updates[("quiet", "objects")] == 0 and updates[("building", "objects")] >= 1


def test_save_and_load_restore_the_layers_through_the_database(rospy_node, layer_server, building_learnt):
    import rospy

    from ros_mongo import open_store

    _, db_url = layer_server

    def located():
        answer = located_in_building(rospy_node)
        return sorted((c.class_name, round(c.mean.x, 9), round(c.mean.y, 9), round(c.support, 9))
                      for c in answer.clusters)
    before = located()
    saved = call(rospy_node, "save_clusters", SaveClusters, region_id="", layer="")
    assert saved.success and saved.clusters >= len(before) and saved.timestamp.endswith("Z")
    with open_store(db_url) as store:
        stored = list(store.find_messages(tags=["objects", saved.timestamp]))
    assert [s.id for s in stored] == [saved.id] and len(stored[0].message().clusters) == saved.clusters
    # forget the building (an empty set for its objects layer on the restore topic) ...
    wipe = ClusterSet(layers=["building/objects"])
    wipe.header.stamp = rospy.Time.now()
    restore = rospy_node.Publisher("/igmm_layers/restore", ClusterSet, queue_size=1, latch=True)
    restore.publish(wipe)
    wait_until(lambda: not located(), 90, what="the building layer to be emptied")
    restore.unregister()
    # ... and get it back from the database
    loaded = call(rospy_node, "load_clusters", LoadClusters, timestamp=saved.timestamp)
    assert loaded.success and loaded.id == saved.id and loaded.clusters == saved.clusters, loaded.message
    assert located() == before
    latest = call(rospy_node, "load_clusters", LoadClusters, timestamp="")
    assert latest.success and latest.timestamp == saved.timestamp


def test_save_reports_a_missing_or_unreachable_database(rospy_node, start_layer_server):
    dead = f"http://127.0.0.1:{free_port()}/nothing_here"
    start_layer_server("igmm_dead_db", db_url=dead, marker_rate=0.0)
    start_layer_server("igmm_no_db", marker_rate=0.0)
    for name, message in (("igmm_dead_db", "could not save clusters"),
                          ("igmm_no_db", "no database configured")):
        save = rospy_node.ServiceProxy(f"/{name}/save_clusters", SaveClusters)(region_id="", layer="")
        assert not save.success and message in save.message
