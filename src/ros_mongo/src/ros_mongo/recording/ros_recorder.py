"""The ros_mongo_server node: ROS topics (any type) into the recorder core.

Its parameters are `ros_mongo.params.RecorderParams` (config/ros_mongo_server.yaml is generated
from it); the executable nodes/ros_mongo_server runs `start` through robot_common.ros_node.run_node.
"""
import socket
import time
from typing import Dict, Optional

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header, String

from robot_common.ros_node import ros_home
from ros_mongo.compat.legacy import legacy_config
from ros_mongo.errors import SpoolError
from ros_mongo.params import ORIGINAL_TOPICS, RecorderParams, compile_patterns
from ros_mongo.recording.bandwidth import Bandwidth
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.deferral import Deferral
from ros_mongo.recording.ledger import Ledger
from ros_mongo.recording.recorder import Recorder
from ros_mongo.recording.upload_rules import docked_from_battery
from ros_mongo.srv import TriggerEvent, TriggerEventResponse
from ros_mongo.storage.store import open_store

__all__ = ["RecorderNode", "ORIGINAL_TOPICS", "start"]


class RecorderNode:
    """ros_mongo_server: records topics of any type into CouchDB (default) or MongoDB.

    Parameters: `RecorderParams` (each with its default and meaning; the launch file loads them
    from config/ros_mongo_server.yaml); the original mongodb_api's global parameters are honoured
    with a deprecation warning (ros_mongo.compat.legacy). The recorded topics are ~topics, plus
    published topics matching ~include, minus those matching ~exclude; ~max_queue_mb bounds memory,
    the spool at ~spool_path takes what does not fit or cannot be written.
    Subscribes: the recorded topics (rospy.AnyMsg: exact bytes, any type).
    Publishes: /diagnostics (diagnostic_msgs/DiagnosticArray): ERROR with the server's reason while
        writes fail (the messages are kept: spooled), or after a writer restart until writes work;
        WARN after drops or quarantined documents; values received, stored, dropped, rejected,
        quarantined, spooled, spool_pending, spool_mb, queued, queued_bytes, writer_restarts, fault,
        last_fault, session_id, robot_id, spool_policy, the count received per topic
        ("topic <name>") and the count dropped per topic ("dropped <name>", only where any).
        With ~upload_rules also deferred, released, deferred_pending, "rule <name>" (holding
        or releasing, and its condition), and from the ledger per topic "ledger <topic>"
        (recorded, uploaded, waiting, dropped, and the latest drop reason).
    Subscribes also: the dock topics of the upload rules (std_msgs/Bool or
        sensor_msgs/BatteryState, read by their type); with on_event rules ~event (std_msgs/String:
        the reason; keeps every on_event rule's window around now).
    Services: with on_event rules ~trigger_event (ros_mongo/TriggerEvent: reason, before and
        after seconds, 0 for each rule's own; answers success, a message naming each rule's
        window, and the kept windows' start and end; a negative or non-finite before / after
        gets success false and keeps nothing).
    The summary logged at shutdown has the same counts, dropped ones per topic. The ledger is
    saved to <spool_path>.ledger every ~ledger_period and at shutdown (`ros_mongo_bag ledger`).
    """

    def __init__(self, config: RecorderParams):
        self.config = config
        self.include = compile_patterns("include", config.include)
        self.exclude = compile_patterns("exclude", config.exclude)
        self.skip = {rospy.resolve_name(topic) for topic in config.skip_topics}
        node = rospy.get_name().strip("/").replace("/", "_")
        self.session_id = config.session_id or time.strftime("%Y%m%dT%H%M%S") + f"-{node}"
        self.robot_id = config.robot_id or socket.gethostname()
        self.rules = config.upload_policy()  # a bad rules file stops the node before recording
        self.store = open_store(config.db_url, connect=False, **config.store_options())
        spool_path = config.spool_path or str(ros_home() / "ros_mongo" / f"{node}.spool")
        deferral = Deferral(self.rules, spool_path, policy=config.drop_policy(), fsync=config.spool_fsync,
                            min_free_bytes=int(config.spool_min_free_mb * 2 ** 20),
                            now=lambda: rospy.get_rostime().to_sec()).open() \
            if self.rules.deferred else None
        self.ledger = Ledger(spool_path + ".ledger").load()
        self.ledger_values: list = []
        spool = BoundedSpool(spool_path, fsync=config.spool_fsync,
                             max_bytes=int(config.spool_max_mb * 2 ** 20),
                             min_free_bytes=int(config.spool_min_free_mb * 2 ** 20),
                             policy=config.drop_policy()).open()
        self.recorder = Recorder(
            self.store, spool, batch_size=config.batch_size,
            batch_period=config.batch_period, max_queue_bytes=int(config.max_queue_mb * 2 ** 20),
            retry_period=config.retry_period, writers=config.writers, session_id=self.session_id,
            robot_id=self.robot_id, tags=config.tags, topic_tags=config.topic_tags,
            quarantine_path=config.quarantine_path or None, author=config.author,
            decode=config.decode_policy(), chunks=config.chunk_policy(), deferral=deferral,
            bandwidth=Bandwidth(config.upload_max_bytes_per_s))
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
        rospy.Timer(rospy.Duration(self.config.ledger_period), self._save_ledger)
        self.dock_subscribers = [rospy.Subscriber(topic, rospy.AnyMsg, self._dock, callback_args=topic)
                                 for topic in self.rules.dock_topics]
        if self.rules.events:
            self.dock_subscribers.append(rospy.Subscriber("~event", String, self._event_topic))
            rospy.Service("~trigger_event", TriggerEvent, self._event_service)
        rospy.loginfo("recording %s into %s (session %s, robot %s, spool %s of at most %.0f MB; when it "
                      "is full the oldest messages of %s go first)", sorted(self.subscribers),
                      self.store.url, self.session_id, self.robot_id, self.recorder.spool.path,
                      self.config.spool_max_mb, self.recorder.spool.policy.describe())
        return self

    def _subscribe(self, topic: str) -> None:
        if topic in self.subscribers or topic in self.skip or any(p.search(topic) for p in self.exclude):
            return
        if self.rules.mode(topic) == "local":  # never leaves the robot: not sent to central
            return
        self.topic_counts[topic] = 0
        # rospy's default 64 KB receive buffer: a larger one is allocated for every socket read
        # (measured: 16 MB cost 1.6x the CPU at the standard load); queue_size None never drops;
        # without TCP_NODELAY (as rosbag record) the publisher's TCP stack sends 1 kHz messages a few
        # at a time, so rospy's per-read work is shared (measured: a fifth of the receive CPU of
        # 1 kHz odometry); receive times are then those of the read, as in rosbag record
        self.subscribers[topic] = rospy.Subscriber(topic, rospy.AnyMsg, self._receive, callback_args=topic,
                                                   queue_size=None, tcp_nodelay=self.config.tcp_nodelay)

    def _receive(self, msg: rospy.AnyMsg, topic: str) -> None:
        header = msg._connection_header
        stamp = rospy.get_rostime()
        if self.recorder.receive(topic, msg._buff, stamp, header["type"], header["md5sum"],
                                 header.get("message_definition", ""), header.get("latching") == "1",
                                 header.get("callerid", "")):
            self.topic_counts[topic] += 1

    def _dock(self, msg: rospy.AnyMsg, topic: str) -> None:
        """A dock topic's state: std_msgs/Bool data, or sensor_msgs/BatteryState charging / full."""
        msg_type = msg._connection_header["type"]
        if msg_type == "std_msgs/Bool":
            from std_msgs.msg import Bool
            docked = Bool().deserialize(msg._buff).data
        elif msg_type == "sensor_msgs/BatteryState":
            from sensor_msgs.msg import BatteryState
            docked = docked_from_battery(BatteryState().deserialize(msg._buff).power_supply_status)
        else:
            rospy.logerr_throttle(30, f"dock topic {topic} has type {msg_type}: expected std_msgs/Bool "
                                      f"or sensor_msgs/BatteryState (taken as not docked)")
            docked = False
        self.recorder.deferral.set_docked(topic, docked)

    def _event_topic(self, msg: String) -> None:
        self._trigger(msg.data or "event")

    def _event_service(self, request) -> TriggerEventResponse:
        try:
            windows, text = self._trigger(request.reason or "service call", request.before, request.after)
        except ValueError as err:
            return TriggerEventResponse(success=False, message=str(err))
        except SpoolError as err:  # the windows file cannot be written: an operator must act
            rospy.logerr(str(err))
            return TriggerEventResponse(success=False, message=str(err))
        return TriggerEventResponse(success=True, message=text,
                                    start=rospy.Time.from_sec(min(w[1] for w in windows)),
                                    end=rospy.Time.from_sec(max(w[2] for w in windows)))

    def _trigger(self, reason: str, before: float = 0.0, after: float = 0.0) -> tuple:
        """Keep the windows of every on_event rule: ((rule, start, end) of each, a summary)."""
        windows = self.recorder.deferral.trigger(reason, before, after)
        text = "; ".join(f"{rule}: keeping {start:.3f} to {end:.3f}" for rule, start, end in windows)
        rospy.loginfo("event %r: %s", reason, text)
        return windows, text

    def _ledger_now(self) -> dict:
        recorder = self.recorder
        counts = {"recorded": dict(self.topic_counts), "uploaded": recorder.uploaded_by_topic(),
                  "dropped": recorder.dropped_by_topic(),
                  "recycled": recorder.deferral.recycled() if recorder.deferral else {}}
        waiting = recorder.spool.pending_topics() if recorder.spool.pending else {}
        if recorder.deferral is not None:
            for topic, count in recorder.deferral.pending_by_topic().items():
                waiting[topic] = waiting.get(topic, 0) + count
        return self.ledger.combine(counts, waiting, recorder.drop_reasons())

    def _save_ledger(self, _event) -> None:
        try:
            ledger = self._ledger_now()
            self.ledger.save(ledger)
        except SpoolError as err:
            rospy.logerr_throttle(60, str(err))
            return
        self.ledger_values = [KeyValue(f"ledger {topic}", ", ".join(f"{k} {v}" for k, v in row.items()))
                              for topic, row in ledger.items()]

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
        status.values += [KeyValue("spool_mb", f"{self.recorder.spool.size / 2 ** 20:.1f}"),
                          KeyValue("spool_policy", self.recorder.spool.policy.describe())]
        status.values += [KeyValue("fault", fault), KeyValue("last_fault", self.recorder.last_fault)]
        status.values += [KeyValue("session_id", self.session_id), KeyValue("robot_id", self.robot_id)]
        status.values += [KeyValue(f"topic {t}", str(n)) for t, n in sorted(self.topic_counts.items())]
        status.values += [KeyValue(f"dropped {t}", str(n))
                          for t, n in sorted(self.recorder.dropped_by_topic().items())]
        deferral = self.recorder.deferral
        if deferral is not None:
            status.values += [KeyValue(f"rule {name}", ("releasing" if deferral.holds(part) else "holding")
                                       + f" (uploads when {part.rule.condition.describe()})")
                              for name, part in deferral.parts.items()]
        status.values += self.ledger_values
        self.diagnostics.publish(DiagnosticArray(header=Header(stamp=rospy.Time.now()), status=[status]))

    def _log_counts(self, _event) -> None:
        counts = self.recorder.counts()
        if counts != self._last_log:
            rospy.loginfo("recorder: %s", ", ".join(f"{k} {v}" for k, v in counts.items()))
            self._last_log = counts

    def shutdown(self) -> None:
        for subscriber in list(self.subscribers.values()) + getattr(self, "dock_subscribers", []):
            subscriber.unregister()
        counts = self.recorder.stop(self.config.shutdown_timeout)
        self._save_ledger(None)
        self.recorder.spool.close()
        if self.recorder.deferral is not None:
            self.recorder.deferral.close()
        self.store.close()
        rospy.loginfo("recorder stopped: %s", ", ".join(f"{k} {v}" for k, v in counts.items()))
        dropped = self.recorder.dropped_by_topic()
        if dropped:
            rospy.logwarn("recorder dropped, per topic: %s (spool policy: the oldest messages of %s "
                          "go first)", ", ".join(f"{t} {n}" for t, n in sorted(dropped.items())),
                          self.recorder.spool.policy.describe())


def start() -> RecorderNode:
    """Build the recorder node from its parameters and wire it to ROS (for run_node)."""
    config = legacy_config(RecorderParams, "recorder", rospy.get_param("~", {}), rospy.get_param,
                           rospy.logwarn)
    node = RecorderNode(config).setup()
    rospy.on_shutdown(node.shutdown)
    return node
