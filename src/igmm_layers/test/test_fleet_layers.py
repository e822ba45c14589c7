"""The layer server learning from the fleet (~source central): ObjectObservation messages and a
saved cluster set of three robots, each recorded in its own store and pushed to a central CouchDB
database by the store's replicator, read by the node from the central `_changes` feed. Real
processes: one pouchdb-server per robot plus the central one, a roscore and the node. Expected
counts come from what the test recorded, never from the node.
"""
import re
from pathlib import Path

import pytest
import requests
import rospy
from geometry_msgs.msg import Point

from igmm_layers.cluster_store import save_cluster_set
from igmm_layers.msg import ClusterSet, ObjectCluster
from igmm_layers.params import LayerServerConfig
from igmm_layers.srv import LayerInfo, LocateObjects
from robot_common.errors import ConfigError
from robot_common.msg import ObjectObservation
from ros_harness import PouchDBServer, wait_until
from ros_mongo import open_store
from ros_mongo.fleet.replication import CouchDatabase, PushReplication

LONG = 150.0  # seconds: roslaunch start-up and replication on a busy machine
OBSERVATIONS = "/igmm_layers/observations"


def chair(index: int, stamp: float) -> ObjectObservation:
    """A chair near (2, 3) in the map frame (a few centimetres apart)."""
    msg = ObjectObservation(class_name="chair", confidence=0.9,
                            position=Point(2.0 + 0.01 * (index % 5), 3.0 + 0.01 * (index % 3), 0.0))
    msg.header.frame_id = "map"
    msg.header.stamp = rospy.Time.from_sec(stamp + index)
    return msg


def whiteboards(stamp: float) -> ClusterSet:
    """A saved set of two whiteboard clusters, at (8, 1) and (8, 6)."""
    msg = ClusterSet(layers=["default/objects"])
    msg.header.frame_id = "map"
    msg.header.stamp = rospy.Time.from_sec(stamp)
    for y in (1.0, 6.0):
        msg.clusters.append(ObjectCluster(
            class_name="whiteboard", region_id="default", layer="objects", mean=Point(8.0, y, 0.0),
            covariance=[0.04, 0, 0, 0, 0.04, 0, 0, 0, 0], weight=0.5, support=10.0, observations=10,
            first_seen=rospy.Time.from_sec(stamp - 100), last_seen=rospy.Time.from_sec(stamp)))
    return msg


class DetectingRobot:
    """A robot's store with chair detections, pushed to central by the store's replicator."""

    def __init__(self, robot_id: str, work: Path, central_url: str):
        self.robot_id = robot_id
        self.server = PouchDBServer(work / robot_id).start()
        self.url = self.server.database_url("robot_data")
        self.store = open_store(self.url).connect()
        local = CouchDatabase(self.url)
        self.replication = PushReplication.for_robot(local, CouchDatabase(central_url), robot_id)
        self.observations = 0
        self.clusters = 0

    def detect(self, count: int, stamp: float) -> None:
        for _ in range(count):
            self.store.insert_message(OBSERVATIONS, chair(self.observations, stamp),
                                      robot_id=self.robot_id)
            self.observations += 1

    def save_clusters(self, msg: ClusterSet) -> None:
        save_cluster_set(self.url, msg, self.robot_id)
        self.clusters += len(msg.clusters)

    def close(self) -> None:
        self.store.close()
        self.server.stop()


def central_documents(central_url: str):
    """Message documents per (robot, type) in central."""
    answer = requests.get(central_url + "/_all_docs", params={"include_docs": "true"}, timeout=60)
    answer.raise_for_status()
    counts = {}
    for row in answer.json()["rows"]:
        doc = row.get("doc") or {}
        if doc.get("kind") == "message":
            key = (doc.get("robot_id"), doc.get("type"))
            counts[key] = counts.get(key, 0) + 1
    return counts


def learned(text: str):
    """{robot: (observations, saved clusters)} as the layer_info message says it."""
    return {robot: (int(obs), int(clusters)) for robot, obs, clusters in
            re.findall(r"(\w+): (\d+) observations, (\d+) saved clusters", text)}


def test_source_central_needs_a_central_url():
    config = LayerServerConfig.from_params({"source": "central", "central_url": "http://c:5984/fleet"})
    assert (config.source, config.central.central_url, config.central_clusters) == (
        "central", "http://c:5984/fleet", False)
    assert LayerServerConfig.from_params({}).source == "topic"
    with pytest.raises(ConfigError, match="central_url"):
        LayerServerConfig.from_params({"source": "central"})
    with pytest.raises(ConfigError) as caught:
        LayerServerConfig.from_params({"source": "central", "central_url": "couch://u:hunter2@c/f"})
    assert "hunter2" not in str(caught.value)


@pytest.mark.ros
@pytest.mark.db
def test_layers_learn_every_robots_detections_and_saved_clusters_through_central(
        start_layer_server, rospy_node, tmp_path):
    central = PouchDBServer(tmp_path / "central").start()
    central_url = central.database_url("fleet")
    assert requests.put(central_url, timeout=30).status_code == 201
    robots = []
    try:
        robots = [DetectingRobot(f"robot{i}", tmp_path, central_url) for i in (1, 2, 3)]
        stamp = 1_700_000_000.0
        for robot, count in zip(robots, (6, 9, 12)):
            robot.detect(count, stamp)
        robots[1].save_clusters(whiteboards(stamp + 500))
        for robot in robots:
            robot.replication.start()
        wanted = {(r.robot_id, "robot_common/ObjectObservation"): r.observations for r in robots}
        wanted[("robot2", "igmm_layers/ClusterSet")] = 1
        wait_until(lambda: central_documents(central_url) == wanted, LONG,
                   what="every robot's detections and cluster set central")

        start_layer_server("fleet_layers", source="central", central_url=central_url,
                           central_clusters=True, marker_rate=0.0)
        info = rospy_node.ServiceProxy("/fleet_layers/layer_info", LayerInfo)

        def caught_up():
            expected = {r.robot_id: (r.observations, r.clusters) for r in robots}
            return learned(info().message) == expected
        wait_until(caught_up, LONG, what="the detections of all three robots learnt")
        text = info().message
        assert "learned from 3 robots" in text and f"central {central_url}" in text
        assert learned(text)["robot2"] == (9, 2)
        answer = info()
        # each saved cluster counts as many observations as its support (10)
        assert answer.dropped == 0 and answer.applied == 6 + 9 + 12 + 2 * 10
        locate = rospy_node.ServiceProxy("/fleet_layers/locate_objects", LocateObjects)
        chairs = locate(class_name="chair").clusters
        assert len(chairs) == 1 and abs(chairs[0].mean.x - 2.02) < 0.05 \
            and abs(chairs[0].mean.y - 3.01) < 0.05
        assert chairs[0].observations == 27
        boards = locate(class_name="whiteboard").clusters
        assert sorted(round(c.mean.y) for c in boards) == [1, 6]

        # refresh: a robot's later detections reach the running server through central
        robots[2].detect(4, stamp + 1000)
        wait_until(caught_up, LONG, what="robot3's new detections learnt")
        assert learned(info().message)["robot3"] == (16, 0)
    finally:
        for robot in robots:
            robot.close()
        central.stop()
