"""The ros_mongo_retriever node: stored messages back onto ROS topics (exact bytes).

Its parameters are `ros_mongo.params.RetrieverParams` (config/ros_mongo_retriever.yaml is generated
from it); the executable nodes/ros_mongo_retriever runs `start` through robot_common.ros_node.run_node.
"""
import json
import struct
import threading
import time
import warnings
from typing import Dict, Tuple

import rosgraph
import rospy
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger, TriggerResponse

from ros_mongo.compat.legacy import legacy_config, original_document
from ros_mongo.errors import QueryError, StoreError
from ros_mongo.params import RetrieverParams, configured_query
from ros_mongo.query import Query, parse_query
from ros_mongo.records import TopicInfo
from ros_mongo.replay.replay import Replayer, ReplayItem
from ros_mongo.srv import Count, CountResponse, SensorData, SensorDataResponse, Start, StartResponse
from ros_mongo.storage.store import open_store

__all__ = ["RetrieverNode", "raw_class", "start"]


class RetrieverNode:
    """ros_mongo_retriever: replays stored messages onto `<topic><output_suffix>` topics.

    Parameters: `RetrieverParams` (each with its default and meaning; the launch file loads them
    from config/ros_mongo_retriever.yaml). Small messages are written synchronously by the player
    (exact timing: a subscriber that cannot keep up slows the replay down); larger ones than
    ~sync_max_bytes go through a queue of ~queue_size per subscriber.
    Publishes: <topic><output_suffix> for each stored topic the query can return (its stored type,
        md5sum, definition and latching; exact stored bytes); /clock (rosgraph_msgs/Clock) if asked.
    Services: ~count (ros_mongo/Count), ~start (ros_mongo/Start), ~stop (std_srvs/Trigger),
        ~sensor_data (ros_mongo/SensorData: matching messages in the original mongodb_api's form).
    The original mongodb_api's global parameters are honoured with a deprecation warning
    (ros_mongo.compat.legacy).
    """

    def __init__(self, config: RetrieverParams):
        self.config = config
        self.query = configured_query(config)
        self.store = open_store(config.db_url, connect=False, timeout=config.db_timeout,
                                credentials_file=config.db_credentials_file or None)
        self.publishers: Dict[str, Tuple[TopicInfo, rospy.Publisher]] = {}
        self._lock = threading.Lock()
        self.clock_pub = rospy.Publisher("/clock", Clock, queue_size=10) if config.publish_clock else None
        self.replayer = Replayer(
            self.store, self._publish, clock=self._clock if self.clock_pub else None,
            rate=config.rate, start_offset=config.start_offset, duration=config.duration,
            loop=config.loop, fixed_rate=config.fixed_rate,
            clock_period=1.0 / config.clock_rate, prefetch=config.prefetch,
            prefetch_mb=config.prefetch_mb, preroll_timeout=config.preroll_timeout,
            lane_min_bytes=config.lane_min_bytes)

    def setup(self) -> "RetrieverNode":
        rospy.Service("~count", Count, self._count)
        rospy.Service("~start", Start, self._start)
        rospy.Service("~stop", Trigger, self._stop)
        rospy.Service("~sensor_data", SensorData, self._sensor_data)
        if self.config.autostart:
            threading.Timer(self.config.start_delay, self._autostart).start()
        return self

    def _autostart(self) -> None:
        ok, message = self.start(self.query)
        (rospy.loginfo if ok else rospy.logerr)(message)

    def start(self, query: Query) -> Tuple[bool, str]:
        try:
            self._advertise(query)
        except StoreError as err:
            return False, f"cannot start replay: {err}"
        self._wait_for_subscribers(self.config.start_delay)
        self.replayer.start(query)
        outputs = sorted(p.resolved_name for _, p in self.publishers.values())
        return True, f"replaying {query.describe()} onto {outputs}"

    def _advertise(self, query: Query) -> None:
        """A publisher for every stored topic the query can return (before playing, so subscribers
        are connected when the first message goes out)."""
        for info in self.store.topics():
            if (query.topics and info.topic not in query.topics) or \
                    (query.msg_type and info.msg_type != query.msg_type):
                continue
            with self._lock:
                if info.topic in self.publishers:
                    continue
                sample = next(iter(self.store.find(Query(topics=[info.topic], msg_type=info.msg_type),
                                                   limit=1, decoded=False)), None)
                # small messages: written at once by the player (exact timing); large ones through
                # a queue and a writer thread per subscriber (a slow subscriber does not hold up others)
                queued = sample is not None and sample.size > self.config.sync_max_bytes
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # rospy warns about synchronous publishers
                    publisher = rospy.Publisher(info.topic + self.config.output_suffix, raw_class(info),
                                                latch=info.latching,
                                                queue_size=self.config.queue_size if queued else None)
                self.publishers[info.topic] = (info, publisher)

    def _wait_for_subscribers(self, timeout: float) -> None:
        """Wait (at most `timeout`) until every subscriber the master knows of is connected."""
        master = rosgraph.Master(rospy.get_name())
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not rospy.is_shutdown():
            try:
                subscribed = {name: len(nodes) for name, nodes in master.getSystemState()[1]}
            except Exception:  # noqa: BLE001 - master busy: play without waiting
                return
            if all(p.get_num_connections() >= subscribed.get(p.resolved_name, 0)
                   for _, p in self.publishers.values()):
                return
            time.sleep(0.02)

    def _publish(self, stored: ReplayItem) -> None:
        entry = self.publishers.get(stored.topic)
        if entry is None or entry[0].md5sum != stored.md5sum:
            rospy.logwarn_throttle(10, f"skipping {stored.topic} message of type {stored.msg_type}: "
                                       f"no publisher for it")
            return
        if _write_direct(entry[1], stored.raw):
            return
        message = entry[1].data_class()
        message._buff = stored.raw
        entry[1].publish(message)

    def _clock(self, stamp) -> None:
        self.clock_pub.publish(Clock(clock=stamp))

    def _query_of(self, text: str) -> Query:
        return parse_query(text) if text.strip() else self.query

    def _count(self, request) -> CountResponse:
        try:
            query = self._query_of(request.query)
            count = self.store.count(query)
        except StoreError as err:
            return CountResponse(success=False, message=str(err), count=0)
        return CountResponse(success=True, message=f"{count} messages match {query.describe()}", count=count)

    def _start(self, request) -> StartResponse:
        try:
            query = self._query_of(request.query)
        except QueryError as err:
            return StartResponse(success=False, message=str(err))
        ok, message = self.start(query)
        return StartResponse(success=ok, message=message)

    def _sensor_data(self, request) -> SensorDataResponse:
        if not request.query.strip():
            return SensorDataResponse(success=False, message="no query given, e.g. 'tags lidar'")
        limit = request.limit if request.limit > 0 else 100
        try:
            query = parse_query(request.query)
            count = self.store.count(query)
            documents = [json.dumps(original_document(stored), default=str)
                         for stored in self.store.find(query, limit=limit)]
        except StoreError as err:
            return SensorDataResponse(success=False, message=str(err), count=0)
        return SensorDataResponse(success=True, count=count, documents=documents,
                                  message=f"{count} messages match {query.describe()}; "
                                          f"{len(documents)} returned")

    def _stop(self, _request) -> TriggerResponse:
        stopped = self.replayer.stop()
        return TriggerResponse(success=True, message=f"stopped after {self.replayer.published} messages"
                               if stopped else "nothing was playing")

    def shutdown(self) -> None:
        self.replayer.stop()
        self.store.close()


def raw_class(info: TopicInfo) -> type:
    """A message class that publishes stored bytes as they are, announcing the stored type."""
    return type("StoredBytes", (rospy.AnyMsg,), {
        "_type": info.msg_type, "_md5sum": info.md5sum, "_full_text": info.definition,
        "_has_header": False, "__slots__": []})


_LENGTH = struct.Struct("<I")
_PUBLISHER_IMPL = ("acquire", "release", "closed", "is_latch", "latch", "has_connections", "seq",
                   "connections", "message_data_sent")


def _write_direct(publisher: rospy.Publisher, raw: bytes) -> bool:
    """Publish stored bytes as rospy's `Publisher.publish` does for a message without a header to
    stamp (TCPROS: the 4-byte length, then the bytes, to every subscriber), but with one gathering
    socket write per subscriber that copies nothing: rospy copies the bytes into its buffer and out
    again first, which holds the interpreter (a few hundred microseconds for a 900 KB image) and
    delays the other topics' messages. False (nothing sent) when this rospy's publisher does not
    look as expected: publish the usual way then."""
    impl = publisher.impl
    if impl is None or not all(hasattr(impl, name) for name in _PUBLISHER_IMPL):
        return False
    failed = []
    header = _LENGTH.pack(len(raw))
    impl.acquire()
    try:
        if impl.closed:
            if rospy.is_shutdown():
                return True
            raise rospy.ROSException("publish() to a closed topic")
        if impl.is_latch:  # new subscribers get the latched message the usual way
            latched = publisher.data_class()
            latched._buff = raw
            impl.latch = latched
        if not impl.has_connections():
            return True
        impl.seq += 1
        for connection in list(impl.connections):
            sock = getattr(connection, "socket", None)
            if sock is None or getattr(connection, "done", False) or rospy.is_shutdown():
                continue
            try:
                _send_all(sock, header, raw)
                connection.stat_bytes += len(raw) + 4
                connection.stat_num_msg += 1
            except OSError:  # as rospy: a failing connection is closed, the others go on
                failed.append(connection)
        impl.message_data_sent += len(raw) + 4
    finally:
        impl.release()
    for connection in failed:
        try:
            connection.close()  # removes itself from the publisher
        except Exception:  # noqa: BLE001 - as rospy
            pass
    return True


def _send_all(sock, header: bytes, raw: bytes) -> None:
    """`header` then `raw` on a blocking socket, gathered (sendmsg), however much each call takes."""
    body = memoryview(raw)
    sent = sock.sendmsg([header, body])
    while sent < len(header) + len(body):
        if sent < len(header):
            sent += sock.sendmsg([header[sent:], body])
        else:
            sent += sock.sendmsg([body[sent - len(header):]])


def start() -> RetrieverNode:
    """Build the retriever node from its parameters and wire it to ROS (for run_node)."""
    config = legacy_config(RetrieverParams, "retriever", rospy.get_param("~", {}), rospy.get_param,
                           rospy.logwarn)
    node = RetrieverNode(config).setup()
    rospy.on_shutdown(node.shutdown)
    return node
