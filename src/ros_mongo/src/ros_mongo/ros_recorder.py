"""The ros_mongo_server node: ROS topics (any type) into the recorder core.

Its parameters are `RecorderConfig` (config/ros_mongo_server.yaml is generated from it).
"""
import re
import socket
import time
from dataclasses import dataclass
from typing import Dict, List, Optional

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from robot_common.ros_node import ros_home, run_node
from ros_mongo.allocator import keep_freed_memory
from ros_mongo.errors import StoreError
from ros_mongo.legacy import legacy_config
from ros_mongo.recorder import Recorder
from ros_mongo.spool import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES, Spool
from ros_mongo.store import open_store

__all__ = ["RecorderNode", "RecorderConfig", "ORIGINAL_TOPICS", "main"]

ORIGINAL_TOPICS = ["/camera/rgb/image_raw", "/joint_states", "/scan", "/odom"]
ORIGINAL_TAGS = {"/camera/rgb/image_raw": ["image"], "/joint_states": ["joint_states"],
                 "/scan": ["lidar"], "/odom": ["odom"]}


@dataclass
class RecorderConfig(NodeConfig):
    """The ros_mongo_server node's parameters."""

    db_url: str = param("http://127.0.0.1:5984/robot_data",
                        "http(s):// CouchDB or mongodb:// MongoDB database URL")
    db_credentials_file: str = param("", "a file holding 'user:password' (or 'password') for db_url, so "
                                         "the password stays out of db_url, ps and parameter listings; "
                                         "empty: the environment's ROS_MONGO_DB_PASSWORD, if set")
    topics: List[str] = param(ORIGINAL_TOPICS, "topics always recorded (the four original ones)")
    include: List[str] = param([], "regular expressions: also record published topics whose name "
                                   "matches one")
    exclude: List[str] = param(["^/rosout", "_mongo$", "^/diagnostics", "^/clock$"],
                               "regular expressions: never record topics whose name matches one")
    discovery_period: float = param(1.0, "seconds between looks for new publishers (with include)")
    batch_size: int = param(500, "messages per bulk write, at most")
    batch_period: float = param(0.2, "seconds a message waits for its bulk write, at most")
    max_queue_mb: float = param(1024.0, "received data waiting in memory (MB); beyond it messages go "
                                        "to the spool undecoded, so a slow database costs no messages")
    retry_period: float = param(1.0, "seconds between probes while the database is unreachable")
    writers: int = param(2, "writer threads (one encodes while another waits for the database)")
    spool_path: str = param("", "the spool file for database outages; empty: "
                                "$ROS_HOME/ros_mongo/<node>.spool")
    spool_fsync: bool = param(False, "fsync every spool append (survives power loss, not only a crash)")
    spool_max_mb: float = param(DEFAULT_MAX_BYTES / 2 ** 20, "the spool file's size limit (MB); beyond "
                                                             "it (and a full queue) messages are dropped")
    spool_min_free_mb: float = param(DEFAULT_MIN_FREE_BYTES / 2 ** 20,
                                     "free disk space (MB) the spool always leaves, like rosbag record "
                                     "--min-space")
    quarantine_path: str = param("", "where documents the database refuses on their own merits are "
                                     "kept; empty: <spool_path>.quarantine")
    db_tls_ca_file: str = param("", "CouchDB over https: a CA bundle for a private CA (empty: the "
                                    "system's); MongoDB: use the URL option tlsCAFile")
    db_tls_cert_file: str = param("", "CouchDB over https: a client certificate (PEM); MongoDB: the "
                                      "URL option tlsCertificateKeyFile")
    db_tls_key_file: str = param("", "CouchDB over https: the client certificate's key (PEM), if not "
                                     "in db_tls_cert_file")
    session_id: str = param("", "session id on every message; empty: <start time>-<node>")
    robot_id: str = param("", "robot id on every message; empty: the host name")
    tags: List[str] = param([], "tags on every message")
    author: str = param("", "author on every message (queried as 'author <name>'); empty: none")
    topic_tags: Dict[str, List[str]] = param(ORIGINAL_TAGS, "tags per topic (the original "
                                                            "image/joint_states/lidar/odom)")
    blob_threshold: int = param(262144, "serialized messages larger than this (bytes) go to "
                                        "attachments / GridFS")
    db_timeout: float = param(5.0, "seconds a database request may take")
    diagnostics_period: float = param(1.0, "seconds between /diagnostics messages")
    log_period: float = param(10.0, "seconds between count lines in the log (when they changed)")
    shutdown_timeout: float = param(10.0, "seconds to flush and drain on shutdown")

    def check(self) -> None:
        _patterns("include", self.include)
        _patterns("exclude", self.exclude)
        if self.spool_max_mb <= 0 or self.spool_min_free_mb < 0:
            raise ConfigError(f"~spool_max_mb must be positive and ~spool_min_free_mb not negative, got "
                              f"{self.spool_max_mb!r} and {self.spool_min_free_mb!r}")
        tls = [self.db_tls_ca_file, self.db_tls_cert_file, self.db_tls_key_file]
        if any(tls) and not self.db_url.lower().startswith("https://"):
            raise ConfigError("~db_tls_ca_file / ~db_tls_cert_file / ~db_tls_key_file need an https:// "
                              "CouchDB ~db_url (MongoDB takes its TLS options in the URL)")

    def store_options(self) -> Dict[str, object]:
        """open_store options (the TLS ones only where set; the credentials file, if any)."""
        options: Dict[str, object] = {"timeout": self.db_timeout, "blob_threshold": self.blob_threshold,
                                      "credentials_file": self.db_credentials_file or None}
        for key, value in (("tls_ca_file", self.db_tls_ca_file), ("tls_cert_file", self.db_tls_cert_file),
                           ("tls_key_file", self.db_tls_key_file)):
            if value:
                options[key] = value
        return options


class RecorderNode:
    """ros_mongo_server: records topics of any type into CouchDB (default) or MongoDB.

    Parameters: `RecorderConfig` (each with its default and meaning; the launch file loads them
    from config/ros_mongo_server.yaml); the original mongodb_api's global parameters are honoured
    with a deprecation warning (ros_mongo.legacy). The recorded topics are ~topics, plus published topics
    matching ~include, minus those matching ~exclude; ~max_queue_mb bounds memory, the spool at
    ~spool_path takes what does not fit or cannot be written.
    Subscribes: the recorded topics (rospy.AnyMsg: exact bytes, any type).
    Publishes: /diagnostics (diagnostic_msgs/DiagnosticArray): ERROR with the server's reason while
        writes fail (the messages are kept: spooled), or after a writer restart until writes work;
        WARN after drops or quarantined documents; values received, stored, dropped, rejected,
        quarantined, spooled, spool_pending, queued, queued_bytes, writer_restarts, fault,
        last_fault, and the count per topic.
    """

    def __init__(self, config: RecorderConfig):
        self.config = config
        self.include = _patterns("include", config.include)
        self.exclude = _patterns("exclude", config.exclude)
        node = rospy.get_name().strip("/").replace("/", "_")
        self.session_id = config.session_id or time.strftime("%Y%m%dT%H%M%S") + f"-{node}"
        self.robot_id = config.robot_id or socket.gethostname()
        self.store = open_store(config.db_url, connect=False, **config.store_options())
        spool_path = config.spool_path or str(ros_home() / "ros_mongo" / f"{node}.spool")
        spool = Spool(spool_path, fsync=config.spool_fsync, max_bytes=int(config.spool_max_mb * 2 ** 20),
                      min_free_bytes=int(config.spool_min_free_mb * 2 ** 20)).open()
        self.recorder = Recorder(
            self.store, spool, batch_size=config.batch_size,
            batch_period=config.batch_period, max_queue_bytes=int(config.max_queue_mb * 2 ** 20),
            retry_period=config.retry_period, writers=config.writers, session_id=self.session_id,
            robot_id=self.robot_id, tags=config.tags, topic_tags=config.topic_tags,
            quarantine_path=config.quarantine_path or None, author=config.author)
        self.subscribers: Dict[str, rospy.Subscriber] = {}
        self.topic_counts: Dict[str, int] = {}
        self._last_log: Optional[Dict[str, int]] = None

    def setup(self) -> "RecorderNode":
        self.recorder.start()
        for topic in self.config.topics:
            self._subscribe(rospy.resolve_name(topic))
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=10)
        if self.include:
            self._discover(None)
            rospy.Timer(rospy.Duration(self.config.discovery_period), self._discover)
        rospy.Timer(rospy.Duration(self.config.diagnostics_period), self._publish_diagnostics)
        rospy.Timer(rospy.Duration(self.config.log_period), self._log_counts)
        rospy.loginfo("recording %s into %s (session %s, robot %s, spool %s)", sorted(self.subscribers),
                      self.store.url, self.session_id, self.robot_id, self.recorder.spool.path)
        return self

    def _subscribe(self, topic: str) -> None:
        if topic in self.subscribers or any(p.search(topic) for p in self.exclude):
            return
        self.topic_counts[topic] = 0
        # rospy's default 64 KB receive buffer: a larger one is allocated for every socket read
        # (measured: 16 MB cost 1.6x the CPU at the standard load); queue_size None never drops
        self.subscribers[topic] = rospy.Subscriber(topic, rospy.AnyMsg, self._receive, callback_args=topic,
                                                   queue_size=None, tcp_nodelay=True)

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
        fault = self.recorder.fault
        if fault:
            status.level = DiagnosticStatus.ERROR
            status.message = f"keeping every message (spooling): {fault}"[:500]
        elif counts["dropped"] or counts["rejected"]:
            status.level, status.message = DiagnosticStatus.WARN, "messages were dropped or quarantined"
        else:
            status.level, status.message = DiagnosticStatus.OK, f"recording {len(self.subscribers)} topics"
        status.values = [KeyValue(key, str(value)) for key, value in counts.items()]
        status.values += [KeyValue("fault", fault), KeyValue("last_fault", self.recorder.last_fault)]
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
        counts = self.recorder.stop(self.config.shutdown_timeout)
        self.recorder.spool.close()
        self.store.close()
        rospy.loginfo("recorder stopped: %s", ", ".join(f"{k} {v}" for k, v in counts.items()))


def _patterns(name: str, values: List[str]) -> List["re.Pattern"]:
    try:
        return [re.compile(v) for v in values]
    except (re.error, TypeError) as err:
        raise ConfigError(f"~{name} holds a bad regular expression: {err}") from None


def _start() -> RecorderNode:
    config = legacy_config(RecorderConfig, "recorder", rospy.get_param("~", {}), rospy.get_param,
                           rospy.logwarn)
    node = RecorderNode(config).setup()
    rospy.on_shutdown(node.shutdown)
    return node


def main() -> int:
    """The ros_mongo_server executable: exit status 1 with one line on a bad configuration."""
    keep_freed_memory()  # image-sized buffers reuse memory instead of fresh pages (ros_mongo.allocator)
    return run_node("ros_mongo_server", _start, loggers=("ros_mongo",), fatal=(StoreError, ValueError))
