"""The ros_mongo_retriever node: stored messages back onto ROS topics (exact bytes)."""
import sys
import threading
import time
import warnings
from typing import Dict, Tuple

import rosgraph
import rospy
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger, TriggerResponse

from ros_mongo.errors import QueryError, StoreError
from ros_mongo.query import Query, parse_query, query_from_mapping
from ros_mongo.records import TopicInfo
from ros_mongo.replay import Replayer, ReplayItem
from ros_mongo.ros_common import ConfigError, read_params, route_logging
from ros_mongo.srv import Count, CountResponse, Start, StartResponse
from ros_mongo.store import open_store

__all__ = ["RetrieverNode", "DEFAULTS", "main"]

DEFAULTS = {
    "db_url": "http://127.0.0.1:5984/robot_data",
    "query": "",
    "topics": [],
    "type": "",
    "tags": [],
    "session_id": "",
    "robot_id": "",
    "start_time": 0.0,
    "end_time": 0.0,
    "fields": {},
    "output_suffix": "_mongo",
    "rate": 1.0,
    "start_offset": 0.0,
    "duration": 0.0,
    "loop": False,
    "fixed_rate": 0.0,
    "publish_clock": False,
    "clock_rate": 100.0,
    "autostart": True,
    "start_delay": 1.0,
    "prefetch": 100000,
    "prefetch_mb": 1024.0,
    "preroll_timeout": 15.0,
    "queue_size": 100,
    "sync_max_bytes": 16777216,
    "lane_min_bytes": 65536,
    "db_timeout": 10.0,
}


class RetrieverNode:
    """ros_mongo_retriever: replays stored messages onto `<topic><output_suffix>` topics.

    Parameters (defaults in config/ros_mongo_retriever.yaml):
        ~db_url (str, http://127.0.0.1:5984/robot_data): CouchDB http(s):// or mongodb://.
        ~query (str, ""): YAML/JSON mapping or the original "<key> <value>" form ("tags lidar");
            its keys override the parameters below.
        ~topics (list, []), ~type (""), ~tags (list, []), ~session_id (""), ~robot_id (""),
        ~start_time / ~end_time (0.0 = open, seconds), ~fields (dict, {}): the query.
        ~output_suffix ("_mongo"): /scan is replayed on /scan_mongo (remap those names freely).
        ~rate (1.0): speed factor of the recorded timing; ~fixed_rate (0.0): messages/s instead.
        ~start_offset (0.0 s), ~duration (0.0 = all), ~loop (false).
        ~publish_clock (false), ~clock_rate (100.0 Hz): publish /clock with the recorded time.
        ~autostart (true): start at launch; ~start_delay (1.0 s): longest wait before playing for
            the subscribers the master knows of to connect to the output topics.
        ~prefetch (100000 messages), ~prefetch_mb (1024.0): read ahead at most this much; it is
            filled before playing (at most ~preroll_timeout, 15.0 s), because loading while playing
            competes for the processor and costs timing precision on a small machine.
        ~sync_max_bytes (16777216), ~queue_size (100): topics whose messages are larger are published
            through an outgoing queue of queue_size per subscriber, smaller ones synchronously (exact
            timing; a subscriber that cannot keep up slows the replay down: lower this for one).
        ~lane_min_bytes (65536): messages this large are published by a thread of their topic's own
            at their due time, so writing them does not delay other topics.
        ~db_timeout (10.0 s).
    Publishes: <topic><output_suffix> for each stored topic the query can return (its stored type,
        md5sum, definition and latching; exact stored bytes); /clock (rosgraph_msgs/Clock) if asked.
    Services: ~count (ros_mongo/Count), ~start (ros_mongo/Start), ~stop (std_srvs/Trigger).
    """

    def __init__(self, params: Dict):
        self.params = params
        self.query = _configured_query(params)
        self.store = open_store(params["db_url"], connect=False, timeout=params["db_timeout"])
        self.publishers: Dict[str, Tuple[TopicInfo, rospy.Publisher]] = {}
        self._lock = threading.Lock()
        self.clock_pub = rospy.Publisher("/clock", Clock, queue_size=10) if params["publish_clock"] else None
        self.replayer = Replayer(
            self.store, self._publish, clock=self._clock if self.clock_pub else None,
            rate=params["rate"], start_offset=params["start_offset"], duration=params["duration"],
            loop=params["loop"], fixed_rate=params["fixed_rate"],
            clock_period=1.0 / params["clock_rate"], prefetch=params["prefetch"],
            prefetch_mb=params["prefetch_mb"], preroll_timeout=params["preroll_timeout"],
            lane_min_bytes=params["lane_min_bytes"])

    def setup(self) -> "RetrieverNode":
        rospy.Service("~count", Count, self._count)
        rospy.Service("~start", Start, self._start)
        rospy.Service("~stop", Trigger, self._stop)
        if self.params["autostart"]:
            threading.Timer(self.params["start_delay"], self._autostart).start()
        return self

    def _autostart(self) -> None:
        ok, message = self.start(self.query)
        (rospy.loginfo if ok else rospy.logerr)(message)

    def start(self, query: Query) -> Tuple[bool, str]:
        try:
            self._advertise(query)
        except StoreError as err:
            return False, f"cannot start replay: {err}"
        self._wait_for_subscribers(self.params["start_delay"])
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
                queued = sample is not None and sample.size > self.params["sync_max_bytes"]
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # rospy warns about synchronous publishers
                    publisher = rospy.Publisher(info.topic + self.params["output_suffix"], raw_class(info),
                                                latch=info.latching,
                                                queue_size=self.params["queue_size"] if queued else None)
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


def _configured_query(params: Dict) -> Query:
    mapping = {"topics": params["topics"], "type": params["type"], "tags": params["tags"],
               "session_id": params["session_id"], "robot_id": params["robot_id"],
               "start_time": params["start_time"] or None, "end_time": params["end_time"] or None,
               "fields": params["fields"] or None}
    try:
        if params["query"].strip():
            text_query = parse_query(params["query"])
            mapping.update({k: v for k, v in _as_mapping(text_query).items() if v not in (None, [], {})})
        return query_from_mapping(mapping)
    except QueryError as err:
        raise ConfigError(f"bad query: {err}") from None


def _as_mapping(query: Query) -> Dict:
    return {"topics": query.topics, "type": query.msg_type, "tags": query.tags,
            "session_id": query.session_id, "robot_id": query.robot_id, "start_time": query.start_time,
            "end_time": query.end_time, "fields": query.fields}


def main() -> int:
    sys.setswitchinterval(0.0001)  # the player thread gets the interpreter back soon after it wakes
    rospy.init_node("ros_mongo_retriever")
    route_logging()
    try:
        node = RetrieverNode(read_params(DEFAULTS)).setup()
    except (ConfigError, StoreError, ValueError) as err:
        rospy.logfatal(f"ros_mongo_retriever: {err}")
        return 1
    rospy.spin()
    node.shutdown()
    return 0
