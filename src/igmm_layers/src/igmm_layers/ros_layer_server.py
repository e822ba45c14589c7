"""The layer server node's ROS side: observations in, markers out (services: ros_services.py)."""
import collections
import json
import re
import threading
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
import tf2_geometry_msgs
import tf2_ros
from geometry_msgs.msg import PointStamped
from visualization_msgs.msg import MarkerArray

from igmm_layers.errors import IGMMError, InvalidInputError
from igmm_layers.msg import ClusterSet
from igmm_layers.params import LayerServerConfig, LayerServerParams
from igmm_layers.ros_central import CentralSource
from igmm_layers.ros_convert import apply_cluster_set, layer_markers, rotation_matrix, size_covariance
from igmm_layers.ros_services import LayerServices
from robot_common.msg import ObjectObservation
from robot_common.ros_node import read_config
from ros_mongo.urls import warn_password_in_url

__all__ = ["LayerServer", "marker_topic", "start"]

Key = Tuple[str, str]


def marker_topic(region_id: str, kind: str) -> str:
    """The private MarkerArray topic of a layer: ~markers/<region id as a ROS name>/<kind>."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", region_id)
    return f"~markers/{name if name[:1].isalpha() else 'r_' + name}/{kind}"


class LayerServer:
    """Learns object layers from detections and answers queries about them (node `igmm_layers`).

    Parameters (params.LayerServerParams; defaults in config/igmm_layers.yaml, generated from
    it; see the README for details):
      ~map_frame (str, "map"): the frame of all clusters; observations are transformed into it.
      ~default_region (str, "default"): region of observations that name none.
      ~observation_topic (str, "observations"), ~place_observation_topic (str, "place_observations"):
          shared ObjectObservation topics of the objects and regions layers (relative names are
          private: /igmm_layers/observations); the message's region_id picks the region.
      ~layer_defaults (dict): covariance_scale 0.01, region_size 20.0 (sigma_ini = their product,
          m), novelty_constant 0.01, v_min 100, sp_min 3.0, dimensions 2, batch false, max_times 1000.
      ~regions (list, []): per-region layers {region_id, kind, observation_topic, <layer params>};
          an observation_topic subscribes that layer's own topic.
      ~class_hierarchy (dict): groups: furniture, appliance, fixture (see the YAML).
      ~class_colours (dict): [r, g, b] in [0, 1] per class of the generated building (others: a
          hue from the name).
      ~marker_rate (double, 2.0 Hz; 0: no markers), ~pair_method (str, "distance_weighted"),
      ~pair_max_distance (double, 5.0 m), ~db_url (str, ""), ~tf_timeout (double, 0.2 s),
      ~queue_size (int, 10000): observations waiting to be learnt (more are dropped and counted).
      ~source (str, "topic"): "central" learns from every robot's ObjectObservation messages in the
          central fleet database ~central_url (its `_changes` feed; ros_central.py) instead of the
          observation topics; ~central_topics (recorded topics, []: all), ~central_clusters
          (false: also the cluster sets robots saved), ~central_credentials_file.
    Topics:
      in:  ~observations, ~place_observations, per-region topics (robot_common/ObjectObservation);
           ~restore (igmm_layers/ClusterSet): replaces the layers it contains.
      out: ~markers/<region>/<objects|regions> (visualization_msgs/MarkerArray, only when
           subscribed); ~restore (latched, by ~load_clusters).
    Services (ros_services.py): ~lookup_object, ~pair_likelihood, ~alternate_object,
      ~locate_objects, ~count_objects, ~save_clusters, ~load_clusters, ~layer_info (its message
      says, for source central, which robots and how many observations of each were learnt).
    """

    def __init__(self, config: LayerServerConfig):
        self.config = config
        self.layers = config.layer_set()
        self.lock = threading.RLock()  # guards self.layers and the counters
        self._queue: collections.deque = collections.deque()
        self._wake = threading.Condition()
        self.received = self.applied = self.dropped = 0
        self.last_drop_reason = ""
        self._marker_pubs: Dict[Key, rospy.Publisher] = {}
        self._marker_state: Dict[Key, List] = {}  # key -> [dirty, connections, arrays published]
        self._restores: Dict[float, Tuple[threading.Event, list]] = {}
        self._running = False
        self.topics: Dict[Key, str] = {}
        self.central: Optional[CentralSource] = None
        # source central: robot -> {"observations": n, "clusters": n} learnt into the layers
        self.learned: Dict[str, Dict[str, int]] = {}

    # --- wiring -----------------------------------------------------------------------------
    def setup(self) -> None:
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(60))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        size = self.config.queue_size
        central = self.config.source == "central"
        if central:
            self.central = CentralSource(self)
        self.subscribers = []
        topics = [(_private(self.config.observation_topic), "", "objects"),
                  (_private(self.config.place_observation_topic), "", "regions")]
        for (region_id, kind), params in self.config.regions.items():
            if params.observation_topic:
                self.topics[(region_id, kind)] = rospy.resolve_name(params.observation_topic)
                topics.append((params.observation_topic, region_id, kind))
        for topic, region_id, kind in topics:
            if central:  # observations recorded on this topic by any robot go to this layer
                self.central.route(rospy.resolve_name(topic), kind, region_id)
            else:
                self.subscribers.append(rospy.Subscriber(
                    topic, ObjectObservation, self._enqueue_observation,
                    callback_args=(region_id, kind), queue_size=size))
        self.restore_pub = rospy.Publisher("~restore", ClusterSet, queue_size=2, latch=True)
        self.subscribers.append(rospy.Subscriber("~restore", ClusterSet, self._enqueue_restore,
                                                 queue_size=4))
        for key in list(self.layers.layers):
            self._ensure_marker_pub(key)
        self.services = LayerServices(self)
        self.services.setup()
        self._running = True
        self._worker = threading.Thread(target=self._work, name="igmm_layers_worker", daemon=True)
        self._worker.start()
        if self.central is not None:
            self.central.start()
        if self.config.marker_rate > 0:
            self._timer = rospy.Timer(rospy.Duration(1.0 / self.config.marker_rate), self._publish_markers)
        rospy.on_shutdown(self.stop)

    def stop(self) -> None:
        if self.central is not None:
            self.central.stop()
        with self._wake:
            self._running = False
            self._wake.notify_all()

    # --- intake -------------------------------------------------------------------------------
    def _enqueue_observation(self, msg: ObjectObservation, args: Key) -> None:
        with self._wake:
            self.received += 1
            if len(self._queue) >= self.config.queue_size:
                self._drop(f"queue full ({self.config.queue_size} observations waiting)")
                return
            self._queue.append(("obs", msg, args, rospy.get_time(), None))
            self._wake.notify()

    def enqueue_central(self, msg: ObjectObservation, args: Key, robot: str, what: str) -> None:
        """Queue an observation read from the central database (recorded by `robot`; `what`:
        "observations" or "clusters" is counted in `learned` once learnt, "" is not); waits
        while the queue is full (the feed is not lost)."""
        with self._wake:
            while self._running and len(self._queue) >= self.config.queue_size:
                self._wake.wait(0.5)
            self.received += 1
            self._queue.append(("obs", msg, args, rospy.get_time(), (robot, what)))
            self._wake.notify_all()

    def _enqueue_restore(self, msg: ClusterSet) -> None:
        with self._wake:
            self._queue.append(("restore", msg))
            self._wake.notify()

    def _drop(self, reason: str) -> None:
        self.dropped += 1
        self.last_drop_reason = reason
        rospy.logwarn_throttle(5.0, f"igmm_layers: dropped an observation: {reason}")

    def _work(self) -> None:
        while True:
            with self._wake:
                while self._running and not self._queue:
                    self._wake.wait(0.5)
                if not self._running:
                    return
                items = list(self._queue)
                self._queue.clear()
                self._wake.notify_all()
            batch: List = []
            for item in items:
                if item[0] == "restore":
                    self._learn(batch)
                    batch = []
                    self._restore(item[1])
                else:
                    batch.append(item)
            self._learn(batch)

    def _learn(self, items: List) -> None:
        groups: Dict[Tuple[str, str, str], List] = collections.OrderedDict()
        for _, msg, args, received, origin in items:
            try:
                region_id, kind, row = self._convert(msg, args, received)
            except (InvalidInputError, tf2_ros.TransformException) as err:
                with self._wake:
                    self._drop(str(err))
                continue
            groups.setdefault((region_id, kind, msg.class_name), []).append(row + (origin,))
        for (region_id, kind, class_name), rows in groups.items():
            positions = np.array([r[0] for r in rows])
            covs = None
            if any(r[2] is not None for r in rows):
                covs = np.array([r[2] if r[2] is not None else np.zeros((3, 3)) for r in rows])
            try:
                with self.lock:
                    layer = self.layers.layer(region_id, kind, create=True)
                    layer.observe(class_name, positions, [r[1] for r in rows], covs, [r[3] for r in rows])
                with self._wake:
                    self.applied += len(rows)
                    for row in rows:
                        if row[4] is not None and row[4][1]:
                            tally = self.learned.setdefault(row[4][0], {"observations": 0,
                                                                        "clusters": 0})
                            tally[row[4][1]] += 1
            except IGMMError as err:
                with self._wake:
                    for _ in rows:
                        self._drop(f"{class_name} in {region_id}/{kind}: {err}")
                continue
            self._ensure_marker_pub((layer.region_id, kind))
            self._marker_state[(layer.region_id, kind)][0] = True

    def _convert(self, msg: ObjectObservation, args: Key, received: float):
        topic_region, kind = args
        if topic_region and msg.region_id and msg.region_id != topic_region:
            raise InvalidInputError(f"region_id {msg.region_id!r} on the topic of region {topic_region!r}")
        region_id = topic_region or msg.region_id or self.config.default_region
        if not msg.class_name:
            raise InvalidInputError("observation without class_name")
        if not 0.0 < msg.confidence <= 1.0:
            raise InvalidInputError(f"confidence must be in (0, 1], got {msg.confidence} ({msg.class_name})")
        position = np.array([msg.position.x, msg.position.y, msg.position.z])
        size = np.array([msg.size.x, msg.size.y, msg.size.z])
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(size)) and np.all(size >= 0)):
            raise InvalidInputError(f"non-finite position or negative size ({msg.class_name})")
        frame = msg.header.frame_id.lstrip("/")
        rotation = np.eye(3)
        if frame and frame != self.config.map_frame:
            transform = self.tf_buffer.lookup_transform(self.config.map_frame, frame, msg.header.stamp,
                                                        rospy.Duration(self.config.tf_timeout))
            point = tf2_geometry_msgs.do_transform_point(
                PointStamped(header=msg.header, point=msg.position), transform).point
            position = np.array([point.x, point.y, point.z])
            rotation = rotation_matrix(transform.transform.rotation)
        cov = size_covariance(msg.size, rotation) if np.any(size > 0) else None
        stamp = msg.header.stamp.to_sec() or received
        return region_id, kind, (position, float(msg.confidence), cov, stamp)

    def _restore(self, msg: ClusterSet) -> None:
        try:
            with self.lock:
                result = apply_cluster_set(self.layers, msg)
                keys = list(self.layers.layers)
            rospy.loginfo(f"igmm_layers: restored {result[1]} clusters in {result[0]} layers")
        except IGMMError as err:
            result, keys = err, []
            rospy.logerr(f"igmm_layers: cannot restore a cluster set: {err}")
        for key in keys:
            self._ensure_marker_pub(key)
            self._marker_state[key][0] = True
        waiting = self._restores.get(msg.header.stamp.to_sec())
        if waiting is not None:
            waiting[1].append(result)
            waiting[0].set()

    def publish_restore(self, msg: ClusterSet, timeout: float):
        """Publish a set on ~restore and wait until this node has applied it (for ~load_clusters).

        Returns (layers, clusters) restored, the error that stopped it, or None on timeout.
        """
        stamp = msg.header.stamp.to_sec()
        waiting = self._restores[stamp] = (threading.Event(), [])
        try:
            self.restore_pub.publish(msg)
            return waiting[1][0] if waiting[0].wait(timeout) else None
        finally:
            self._restores.pop(stamp, None)

    # --- markers ------------------------------------------------------------------------------
    def _ensure_marker_pub(self, key: Key) -> None:
        if key not in self._marker_pubs and self.config.marker_rate > 0:
            self._marker_pubs[key] = rospy.Publisher(marker_topic(*key), MarkerArray, queue_size=2)
        self._marker_state.setdefault(key, [True, 0, 0])

    def _publish_markers(self, _event=None) -> None:
        for key, publisher in list(self._marker_pubs.items()):
            state = self._marker_state[key]
            connections = publisher.get_num_connections()
            if connections and (state[0] or connections > state[1]):
                state[0] = False
                with self.lock:
                    layer = self.layers.layers.get(key)
                    markers = layer_markers(layer, self.config.map_frame, rospy.Time.now(),
                                            self.config.class_colours) if layer else None
                if markers is not None:
                    publisher.publish(markers)
                    state[2] += 1
            state[1] = connections

    def marker_updates(self, key: Key) -> int:
        return self._marker_state.get(key, [0, 0, 0])[2]

    def counters(self) -> Tuple[int, int, int, str]:
        with self._wake:
            return self.received, self.applied, self.dropped, self.last_drop_reason

    def learned_status(self) -> str:
        """Source central: which robots and how many of their observations (and saved clusters)
        the layers learnt, and the feed position read; "" for source topic."""
        if self.central is None:
            return ""
        with self._wake:
            learned = {robot: dict(tally) for robot, tally in sorted(self.learned.items())}
        robots = "; ".join(f"{robot}: {tally['observations']} observations, {tally['clusters']} "
                           f"saved clusters" for robot, tally in learned.items()) or "none yet"
        error = f"; last error: {self.central.follower.last_error}" \
            if self.central.follower.last_error else ""
        return (f"learned from {len(learned)} robots: {robots} (central {self.central.shown} "
                f"read to sequence {json.dumps(self.central.seq)}){error}")


def _private(name: str) -> str:
    return name if name.startswith(("/", "~")) else "~" + name


def start() -> LayerServer:
    """The node's start-up: read its parameters, build the server, wire ROS (see LayerServer)."""
    config = LayerServerConfig.from_node_params(read_config(LayerServerParams))
    warn_password_in_url(config.db_url)  # roslaunch prints parameters: say so at once
    server = LayerServer(config)
    server.setup()
    rospy.loginfo(f"igmm_layers: ready; map frame {config.map_frame}, default region "
                  f"{config.default_region}, {len(config.regions)} configured region layers, "
                  f"database {'none' if not config.db_url else 'configured'}, observations from "
                  f"{'the central fleet database' if config.source == 'central' else 'topics'}")
    return server
