"""The ros_mongo_server node: ROS topics (any type) into the recorder core."""
import re
import socket
import time
from typing import Dict, List, Optional

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from ros_mongo.errors import StoreError
from ros_mongo.recorder import Recorder
from ros_mongo.ros_common import ConfigError, read_params, ros_home, route_logging
from ros_mongo.spool import Spool
from ros_mongo.store import open_store

__all__ = ["RecorderNode", "DEFAULTS", "main"]

ORIGINAL_TOPICS = ["/camera/rgb/image_raw", "/joint_states", "/scan", "/odom"]
DEFAULTS = {
    "db_url": "http://127.0.0.1:5984/robot_data",
    "topics": list(ORIGINAL_TOPICS),
    "include": [],
    "exclude": ["^/rosout", "_mongo$", "^/diagnostics", "^/clock$"],
    "discovery_period": 1.0,
    "batch_size": 500,
    "batch_period": 0.2,
    "max_queue_mb": 1024.0,
    "retry_period": 1.0,
    "writers": 2,
    "spool_path": "",
    "spool_fsync": False,
    "session_id": "",
    "robot_id": "",
    "tags": [],
    "topic_tags": {"/camera/rgb/image_raw": ["image"], "/joint_states": ["joint_states"],
                   "/scan": ["lidar"], "/odom": ["odom"]},
    "blob_threshold": 262144,
    "db_timeout": 5.0,
    "diagnostics_period": 1.0,
    "log_period": 10.0,
    "shutdown_timeout": 10.0,
}


class RecorderNode:
    """ros_mongo_server: records topics of any type into CouchDB (default) or MongoDB.

    Parameters (defaults in config/ros_mongo_server.yaml):
        ~db_url (str, http://127.0.0.1:5984/robot_data): http(s):// CouchDB or mongodb:// MongoDB.
        ~topics (list, the four original topics): always recorded.
        ~include (list of regex, []): also record published topics whose name matches one.
        ~exclude (list of regex, [^/rosout, _mongo$, ^/diagnostics, ^/clock$]): never these.
        ~discovery_period (1.0 s): how often new publishers are looked for.
        ~batch_size (500), ~batch_period (0.2 s): a bulk write when either is reached.
        ~max_queue_mb (1024): received data waiting in memory; beyond it messages go to the spool
            (undecoded; decoded when drained), so a slow database costs no messages.
        ~retry_period (1.0 s): probe interval while the database is unreachable.
        ~writers (2): writer threads (one encodes while another waits for the database).
        ~spool_path (str, $ROS_HOME/ros_mongo/<node>.spool): the spool for database outages.
        ~spool_fsync (false): fsync every spool append (survives power loss, not only a crash).
        ~session_id (str, generated), ~robot_id (str, host name), ~tags (list, []): on every message.
        ~topic_tags (dict, the original tags image/joint_states/lidar/odom): tags per topic.
        ~blob_threshold (262144 bytes): larger messages go to attachments / GridFS.
        ~db_timeout (5.0 s), ~diagnostics_period (1.0 s), ~log_period (10.0 s),
        ~shutdown_timeout (10.0 s): time to flush and drain on shutdown.
    Subscribes: the recorded topics (rospy.AnyMsg: exact bytes, any type).
    Publishes: /diagnostics (diagnostic_msgs/DiagnosticArray): received, stored, dropped, rejected,
        spooled, spool_pending, queued, topics.
    """

    def __init__(self, params: Dict):
        self.params = params
        self.include = _patterns("include", params["include"])
        self.exclude = _patterns("exclude", params["exclude"])
        node = rospy.get_name().strip("/").replace("/", "_")
        self.session_id = params["session_id"] or time.strftime("%Y%m%dT%H%M%S") + f"-{node}"
        self.robot_id = params["robot_id"] or socket.gethostname()
        self.store = open_store(params["db_url"], connect=False, timeout=params["db_timeout"],
                                blob_threshold=params["blob_threshold"])
        spool_path = params["spool_path"] or str(ros_home() / "ros_mongo" / f"{node}.spool")
        spool = Spool(spool_path, fsync=params["spool_fsync"]).open()
        self.recorder = Recorder(
            self.store, spool, batch_size=params["batch_size"],
            batch_period=params["batch_period"], max_queue_bytes=int(params["max_queue_mb"] * 2 ** 20),
            retry_period=params["retry_period"], writers=params["writers"], session_id=self.session_id,
            robot_id=self.robot_id, tags=params["tags"], topic_tags=params["topic_tags"])
        self.subscribers: Dict[str, rospy.Subscriber] = {}
        self.topic_counts: Dict[str, int] = {}
        self._last_log: Optional[Dict[str, int]] = None

    def setup(self) -> "RecorderNode":
        self.recorder.start()
        for topic in self.params["topics"]:
            self._subscribe(rospy.resolve_name(topic))
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=10)
        if self.include:
            self._discover(None)
            rospy.Timer(rospy.Duration(self.params["discovery_period"]), self._discover)
        rospy.Timer(rospy.Duration(self.params["diagnostics_period"]), self._publish_diagnostics)
        rospy.Timer(rospy.Duration(self.params["log_period"]), self._log_counts)
        rospy.loginfo("recording %s into %s (session %s, robot %s, spool %s)", sorted(self.subscribers),
                      self.store.url, self.session_id, self.robot_id, self.recorder.spool.path)
        return self

    def _subscribe(self, topic: str) -> None:
        if topic in self.subscribers or any(p.search(topic) for p in self.exclude):
            return
        self.topic_counts[topic] = 0
        self.subscribers[topic] = rospy.Subscriber(topic, rospy.AnyMsg, self._receive, callback_args=topic,
                                                   queue_size=None, buff_size=1 << 24, tcp_nodelay=True)

    def _receive(self, msg: rospy.AnyMsg, topic: str) -> None:
        header = msg._connection_header
        stamp = rospy.get_rostime()
        if self.recorder.receive(topic, msg._buff, stamp, header["type"], header["md5sum"],
                                 header.get("message_definition", ""), header.get("latching") == "1",
                                 header.get("callerid", "")):
            self.topic_counts[topic] += 1

    def _discover(self, _event) -> None:
        try:
            published = rospy.get_published_topics()
        except Exception as err:  # noqa: BLE001 - master hiccups: try again next period
            rospy.logwarn_throttle(30, f"cannot list published topics: {err}")
            return
        for topic, _type in published:
            if any(p.search(topic) for p in self.include):
                self._subscribe(topic)

    def _publish_diagnostics(self, _event) -> None:
        counts = self.recorder.counts()
        status = DiagnosticStatus(name="ros_mongo_server: recorder", hardware_id=self.store.url)
        if counts["dropped"] or counts["rejected"]:
            status.level, status.message = DiagnosticStatus.WARN, "messages were dropped or rejected"
        elif not self.recorder.db_ok:
            status.level, status.message = DiagnosticStatus.WARN, "database unreachable: spooling"
        else:
            status.level, status.message = DiagnosticStatus.OK, f"recording {len(self.subscribers)} topics"
        status.values = [KeyValue(key, str(value)) for key, value in counts.items()]
        status.values += [KeyValue("session_id", self.session_id), KeyValue("robot_id", self.robot_id)]
        status.values += [KeyValue(f"topic {t}", str(n)) for t, n in sorted(self.topic_counts.items())]
        self.diagnostics.publish(DiagnosticArray(header=Header(stamp=rospy.Time.now()), status=[status]))

    def _log_counts(self, _event) -> None:
        counts = self.recorder.counts()
        if counts != self._last_log:
            rospy.loginfo("recorder: %s", ", ".join(f"{k} {v}" for k, v in counts.items()))
            self._last_log = counts

    def shutdown(self) -> None:
        for subscriber in self.subscribers.values():
            subscriber.unregister()
        counts = self.recorder.stop(self.params["shutdown_timeout"])
        self.recorder.spool.close()
        self.store.close()
        rospy.loginfo("recorder stopped: %s", ", ".join(f"{k} {v}" for k, v in counts.items()))


def _patterns(name: str, values: List[str]) -> List["re.Pattern"]:
    try:
        return [re.compile(v) for v in values]
    except (re.error, TypeError) as err:
        raise ConfigError(f"~{name} holds a bad regular expression: {err}") from None


def main() -> int:
    rospy.init_node("ros_mongo_server")
    route_logging()
    try:
        node = RecorderNode(read_params(DEFAULTS)).setup()
    except (ConfigError, StoreError, ValueError) as err:
        rospy.logfatal(f"ros_mongo_server: {err}")
        return 1
    rospy.spin()
    node.shutdown()
    return 0
