"""Fleet learning of the layer server (~source central): every robot's detections, and optionally
its saved cluster sets, read from the central fleet database's `_changes` feed.

`CentralSource(server)` follows the feed (ros_mongo.fleet.changes.ChangesFollower) in a thread of its
own and hands each ObjectObservation document to the server's queue with the robot that recorded
it; a saved ClusterSet (~central_clusters) becomes, per cluster, as many observations as its
support (at most MAX_CLUSTER_WEIGHT) at its mean, with a size whose box spread matches the
cluster's covariance. The feed is read from its start at each
start, so a server builds its layers from the fleet's whole history and then refreshes them as
robots' new documents arrive. The server counts what it learned per robot (`LayerServer.learned`).
"""
import math
import threading
from typing import Any, Dict, List, Tuple

import rospy
from geometry_msgs.msg import Vector3

from igmm_layers.cluster_store import CLUSTER_TOPIC
from igmm_layers.msg import ClusterSet
from robot_common.msg import ObjectObservation
from ros_mongo.errors import StoreError

__all__ = ["CentralSource", "OBSERVATION_TYPE", "CLUSTER_SET_TYPE", "cluster_observations",
           "NO_ROBOT"]

OBSERVATION_TYPE = "robot_common/ObjectObservation"
CLUSTER_SET_TYPE = "igmm_layers/ClusterSet"
NO_ROBOT = "(no robot id)"
MAX_CLUSTER_WEIGHT = 1000  # observations one saved cluster counts as, at most

Key = Tuple[str, str]


def cluster_observations(msg: ClusterSet) -> List[Tuple[ObjectObservation, Key]]:
    """One observation per cluster of a saved set, with the (region, layer) it belongs to: at the
    cluster's mean, in the set's frame, seen when the cluster was last seen, with an extent whose
    uniform spread (s^2 / 12 per axis) has the cluster's variances."""
    observations = []
    for cluster in msg.clusters:
        cov = list(cluster.covariance)
        size = Vector3(*(math.sqrt(12.0 * max(cov[4 * i], 0.0)) for i in range(3)))
        obs = ObjectObservation(class_name=cluster.class_name, position=cluster.mean,
                                confidence=1.0, size=size, region_id=cluster.region_id)
        obs.header.frame_id = msg.header.frame_id
        obs.header.stamp = cluster.last_seen
        observations.append((obs, (cluster.region_id, cluster.layer or "objects")))
    return observations


class CentralSource:
    """Follows the central database of ~central_url into the layer server's queue."""

    def __init__(self, server):
        self.server = server
        config = server.config
        types = [OBSERVATION_TYPE] + ([CLUSTER_SET_TYPE] if config.central_clusters else [])
        # central_topics selects observations only (saved cluster sets come on any topic)
        self.follower = config.central.central_follower(types, topics=())
        self.topics = set(config.central.central_topics)
        self.routes: Dict[str, Key] = {}  # recorded topic -> (region, layer) of its observations
        self._stop = threading.Event()
        self.documents = 0  # selected documents read

    @property
    def shown(self) -> str:
        """The central database URL without its password."""
        return self.follower.shown

    def route(self, topic: str, kind: str, region_id: str = "") -> None:
        """Observations recorded on `topic` go to layer `kind` (of `region_id`, if given)."""
        self.routes[topic] = (region_id, kind)

    def start(self) -> None:
        rospy.loginfo(f"igmm_layers: learning from every robot in {self.shown}")
        threading.Thread(target=self._follow, name="igmm_layers_central", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()

    @property
    def seq(self) -> Any:
        """The feed position read so far."""
        return self.follower.since

    def _follow(self) -> None:
        while not self._stop.is_set():
            try:
                for item in self.follower.follow(self._stop):
                    self._take(item.message)
            except Exception as err:  # noqa: BLE001 - keep following; the error is reported
                rospy.logerr_throttle(30, f"igmm_layers: following {self.shown} failed: "
                                          f"{type(err).__name__}: {err}")
                self._stop.wait(5.0)

    def _take(self, stored) -> None:
        robot = stored.robot_id or NO_ROBOT
        if stored.msg_type == CLUSTER_SET_TYPE and stored.topic != CLUSTER_TOPIC:
            return
        if stored.msg_type == OBSERVATION_TYPE and self.topics and stored.topic not in self.topics:
            return
        try:
            msg = stored.message()
        except StoreError as err:
            rospy.logwarn_throttle(10, f"igmm_layers: skipped central document {stored.id}: {err}")
            return
        self.documents += 1
        if stored.msg_type == CLUSTER_SET_TYPE:
            for (obs, key), cluster in zip(cluster_observations(msg), msg.clusters):
                weight = min(max(int(round(cluster.support)), 1), MAX_CLUSTER_WEIGHT)
                self.server.enqueue_central(obs, key, robot, "clusters")
                for _ in range(weight - 1):  # the same cluster: not counted again
                    self.server.enqueue_central(obs, key, robot, "")
        else:
            key = self.routes.get(stored.topic, ("", "objects"))
            self.server.enqueue_central(msg, key, robot, "observations")
