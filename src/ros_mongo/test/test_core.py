"""The ROS-free cores: queries, decoded fields, the spool, the replayer (without a ROS master)."""
import io
import math
import time

import genpy
import pytest
from geometry_msgs.msg import Point, Pose, PoseArray
from nav_msgs.msg import Odometry
from ros_mongo_samples import custom_message, image, joints, odometry, scan
from sensor_msgs.msg import Image, LaserScan
from std_msgs.msg import Int64, String, UInt64MultiArray

from robot_common.errors import ConfigError
from ros_harness import wait_until
from ros_mongo import (
    QueryError,
    SpoolError,
    TopicInfo,
    UnknownTypeError,
    make_record,
    open_store,
    parse_query,
)
from ros_mongo.messages.msgtypes import (
    index_fields,
    message_class,
    reference_fields,
    reference_index_fields,
    to_fields,
)
from ros_mongo.params import RecorderParams, RetrieverParams, configured_query
from ros_mongo.recording.allocator import keep_freed_memory
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.recorder import Recorder
from ros_mongo.recording.spool import Spool
from ros_mongo.records import new_message_id, split_time
from ros_mongo.replay.replay import Replayer
from ros_mongo.storage.documents import query_conditions, to_selector


def serialized(msg) -> bytes:
    buffer = io.BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


# -- queries ---------------------------------------------------------------------------------
def test_original_two_word_query_and_mappings():
    assert parse_query("tags lidar").tags == ["lidar"]
    assert parse_query("topic /scan").topics == ["/scan"]
    assert parse_query("session_id run7").session_id == "run7"
    query = parse_query('{"topics": ["/odom"], "start_time": 10, "fields": {"pose.pose.position.x": [0, 2]}}')
    assert query.topics == ["/odom"] and query.start_time == 10.0
    assert query.fields == {"pose.pose.position.x": {"$gte": 0, "$lte": 2}}
    assert parse_query("  ").describe() == "all messages"


@pytest.mark.parametrize("text,match", [
    ("colour red", "unknown query key"),
    ("[1, 2]", "query must be a mapping"),
    ("{topics: [/a", "neither a YAML/JSON mapping"),
    ("{fields: {x: {$near: 1}}}", "unknown operator"),
    ("{start_time: 5, end_time: 1}", "is after end_time"),
])
def test_malformed_query_text(text, match):
    with pytest.raises(QueryError, match=match):
        parse_query(text)


# -- decoded fields --------------------------------------------------------------------------
def test_fields_are_json_safe():
    scan = LaserScan(ranges=[1.0, math.inf, -math.inf, math.nan], intensities=[0.0] * 5000)
    fields = to_fields(scan)
    assert fields["ranges"] == [1.0, "Infinity", "-Infinity", "NaN"]
    assert fields["intensities"] is None  # longer than max_array_len: only in the raw bytes
    assert to_fields(UInt64MultiArray(data=[2 ** 64 - 1, 1]))["data"] == [float(2 ** 64 - 1), 1]
    assert to_fields(Int64(data=-(2 ** 63)))["data"] == -(2 ** 63)
    image = to_fields(Image(encoding="mono8", data=bytes(1000)))
    assert image["data"] is None and image["encoding"] == "mono8"
    assert to_fields(Image(data=bytes([1, 2, 3])))["data"] == [1, 2, 3]
    poses = to_fields(PoseArray(poses=[Pose(position=Point(1, 2, 3)), Pose()]))
    assert poses["poses"][0]["position"] == {"x": 1, "y": 2, "z": 3} and len(poses["poses"]) == 2


def test_compiled_fields_match_the_reference_converters():
    """The generated per-class converters (the recorder's hot path) give exactly what the generic
    field-by-field converters give, at both levels, for finite and non-finite values alike."""
    odom_nan = odometry()
    odom_nan.twist.twist.linear.y = math.nan
    big = Odometry()
    big.pose.pose.position.x, big.pose.pose.position.y = 1e308, 1e308  # a sum that overflows
    wide = UInt64MultiArray(data=[2 ** 64 - 1])
    wide.layout.data_offset = 7
    messages = [odometry(), odom_nan, big, scan(), image(), joints(), custom_message(), wide,
                Int64(data=-(2 ** 63)), LaserScan(range_max=math.inf, ranges=[math.nan]),
                PoseArray(poses=[Pose(position=Point(1, 2, math.inf)), Pose()])]
    for msg in messages:
        assert to_fields(msg) == reference_fields(msg), msg._type
        assert to_fields(msg, 2) == reference_fields(msg, 2), msg._type
        assert index_fields(msg) == reference_index_fields(msg), msg._type
    assert index_fields(odom_nan)["twist"]["twist"]["linear"]["y"] == "NaN"
    assert to_fields(big)["pose"]["pose"]["position"]["x"] == 1e308
    assert "covariance" not in index_fields(odometry())["pose"]


def test_unknown_type_needs_a_definition():
    with pytest.raises(UnknownTypeError, match="'nowhere_msgs/Thing' with md5sum abc is not installed"):
        message_class("nowhere_msgs/Thing", "abc")
    with pytest.raises(UnknownTypeError, match="cannot build message type"):
        message_class("nowhere_msgs/Thing", "abc", "this is not a message definition !!")
    assert message_class("std_msgs/String", String._md5sum) is String


# -- the spool -------------------------------------------------------------------------------
def _records(n, start=0):
    return [make_record("/chatter", String, serialized(String(data=f"m{i}")), receive=split_time(100 + i))
            for i in range(start, start + n)]


def test_spool_appends_reads_commits_and_survives_reopen(tmp_path):
    path = tmp_path / "rec.spool"
    spool = Spool(path).open()
    info = TopicInfo.of_class("/chatter", String)
    records = _records(5)
    spool.append([info] + records[:3])
    spool.append(records[3:])
    assert spool.pending_records == 5
    entries, offset = spool.read(max_entries=3)
    assert entries == [info] + records[:2]
    spool.commit(offset, 2)
    spool.close()
    spool = Spool(path).open()  # a new recorder finds the rest
    assert spool.pending_records == 3
    entries, offset = spool.read()
    assert entries == records[2:]
    spool.commit(offset, 3)
    assert not spool.pending and path.stat().st_size == 0
    spool.close()


def test_spool_cuts_a_torn_frame_and_is_exclusive(tmp_path):
    path = tmp_path / "rec.spool"
    spool = Spool(path).open()
    spool.append(_records(2))
    with pytest.raises(SpoolError, match="in use by another recorder"):
        Spool(path).open()
    spool.close()
    whole = path.read_bytes()
    path.write_bytes(whole + whole[: len(whole) // 3])  # a killed writer left half a frame
    spool = Spool(path).open()
    assert spool.pending_records == 2 and path.stat().st_size == len(whole)
    spool.append(_records(1, start=2))
    entries, _ = spool.read()
    assert [e.fields["data"] for e in entries] == ["m0", "m1", "m2"]
    spool.close()


# -- the recorder core ---------------------------------------------------------------------
@pytest.mark.db
def test_recorder_spools_what_the_queue_cannot_hold_and_stores_it_decoded(couchdb_url, tmp_path):
    with open_store(couchdb_url) as store:
        spool = BoundedSpool(tmp_path / "rec.spool").open()
        recorder = Recorder(store, spool, max_queue_bytes=100, batch_period=0.05, session_id="s",
                            topic_tags={"/chatter": ["talk"]}).start()
        for i in range(300):  # each message is about 10 bytes: most overflow to the spool
            assert recorder.receive("/chatter", serialized(String(data=f"m{i}")), split_time(100 + i),
                                    String._type, String._md5sum, String._full_text)
        counts = recorder.stop(timeout=30)
        spool.close()
        assert counts["spooled"] > 200 and counts["dropped"] == 0
        assert counts["stored"] == 300 and counts["spool_pending"] == 0
        stored = list(store.find_messages(topic="/chatter"))
    assert [m.fields["data"] for m in stored] == [f"m{i}" for i in range(300)]
    assert {tuple(m.tags) for m in stored} == {("talk",)} and {m.session_id for m in stored} == {"s"}


def test_message_ids_are_distinct_and_keep_their_form():
    ids = [new_message_id(1700000000, 5, "robot 1") for _ in range(1000)]
    assert len(set(ids)) == 1000
    for doc_id in ids:
        stamp, robot, token = doc_id.split("-")
        assert stamp == "1700000000000000005" and robot == "robot%201"
        assert len(token) == 12 and set(token) <= set("0123456789abcdef")
    assert new_message_id(1, 0, token="abc") == "0000000001000000000-abc"


def test_allocator_tuning_applies_on_glibc():
    assert keep_freed_memory() is True  # Debian's C library is glibc


# -- the replayer ----------------------------------------------------------------------------
@pytest.fixture
def replay_store(couchdb_url):
    with open_store(couchdb_url) as store:
        store.put_topic(TopicInfo.of_class("/chatter", String))
        store.insert_records(_records(20))  # receive times 100 .. 119 s
        yield store


@pytest.mark.db
def test_replay_window_rate_and_order(replay_store):
    got = []
    replayer = Replayer(replay_store, lambda m: got.append((time.monotonic(), m)), rate=50.0,
                        start_offset=5.0, duration=10.0)
    replayer.start(parse_query("topic /chatter"))
    assert replayer.wait(10) and replayer.state == "finished"
    assert [m.receive_time for _, m in got] == [105.0 + i for i in range(11)]
    assert got[-1][0] - got[0][0] >= 10.0 / 50.0 - 0.002  # never ahead of the scaled schedule


@pytest.mark.db
@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # reads as the test above does
def test_replay_fixed_rate_loop_and_stop(replay_store):
    got, clock = [], []
    replayer = Replayer(replay_store, got.append, clock=clock.append, fixed_rate=400.0, loop=True)
    replayer.start(parse_query(""))
    wait_until(lambda: len(got) >= 45, 120, what="three loops")
    assert replayer.stop() and replayer.state == "stopped"
    assert [m.receive_time for m in got[:40]] == [100.0 + i % 20 for i in range(40)]
    assert clock and all(isinstance(c, genpy.Time) for c in clock)


@pytest.mark.db
def test_replay_of_nothing_finishes(replay_store):
    replayer = Replayer(replay_store, lambda m: None)
    replayer.start(parse_query("topic /nothing"))
    assert replayer.wait(120) and replayer.state == "finished" and replayer.published == 0


# -- node parameters -----------------------------------------------------------------------------
# (config/*.yaml are generated from these classes; tests/test_structure.py checks they are current)
def test_recorder_config_rejects_a_bad_pattern_and_unknown_keys():
    assert RecorderParams.from_mapping({}).topics == ["/camera/rgb/image_raw", "/joint_states", "/scan",
                                                      "/odom"]
    with pytest.raises(ConfigError, match="~include holds a bad regular expression"):
        RecorderParams.from_mapping({"include": ["("]})
    with pytest.raises(ConfigError, match="unknown parameter"):
        RecorderParams.from_mapping({"batchsize": 10})


def test_decode_levels_read_as_the_parameter_server_returns_them_and_chunk_periods_are_checked():
    # `decode: {nav_msgs/Odometry: index, camera/rgb/image_raw: raw, odom: raw}` as rosparam
    # returns it: keys holding '/' nested, topics without their leading '/'
    config = RecorderParams.from_mapping({"decode": {"nav_msgs": {"Odometry": "index"}, "odom": "raw",
                                                     "camera": {"rgb": {"image_raw": "raw"}}}})
    policy = config.decode_policy()
    assert policy.level("/odom", "nav_msgs/Odometry") == "raw"          # the topic's entry wins
    assert policy.level("/odom_fused", "nav_msgs/Odometry") == "index"  # its type's
    assert policy.level("/camera/rgb/image_raw", "sensor_msgs/Image") == "raw"
    assert policy.level("/scan", "sensor_msgs/LaserScan") == "full"     # ~decode_default
    assert RecorderParams.from_mapping({"chunk_period": 0.25}).chunk_policy().period == 0.25
    for period in (0.0, 1.5):
        with pytest.raises(ConfigError, match="chunk period must be above 0 and at most 1.0"):
            RecorderParams.from_mapping({"chunk_period": period}).chunk_policy()


def test_retriever_config_builds_its_query():
    config = RetrieverParams.from_mapping({"topics": ["/odom", "/scan"], "start_time": 5,
                                           "query": "tags lidar"})
    query = configured_query(config)
    assert query.topics == ["/odom", "/scan"] and query.tags == ["lidar"] and query.start_time == 5.0
    assert query.end_time is None
    with pytest.raises(ConfigError, match="bad query: unknown query key"):
        RetrieverParams.from_mapping({"query": "colour red"})


# -- the one Query -> filter translation ---------------------------------------------------------
def test_query_conditions_render_one_selector_for_both_databases():
    query = parse_query('{topics: [/a, /b], tags: [x], start_time: 1, end_time: 2, '
                        'fields: {pose.x: [0, 1], header.frame_id: map}}')
    # message fields spelled out (ros_mongo.storage.documents): a range holds for the value or one element,
    # numbers only; equality for the value or an element; all under one {"$or": [{"$and": ...}]}
    number = {"$gte": 0, "$lte": 1, "$type": "number"}
    assert to_selector(query_conditions(query)) == {
        "topic": {"$in": ["/a", "/b"]}, "tags": {"$all": ["x"]},
        "receive_time": {"$gte": 1.0, "$lte": 2.0},
        "$or": [{"$and": [
            {"$or": [{"msg.pose.x": number}, {"msg.pose.x": {"$elemMatch": number}}]},
            {"$or": [{"msg.header.frame_id": {"$eq": "map"}},
                     {"msg.header.frame_id": {"$elemMatch": {"$eq": "map"}}}]}]}]}
    assert to_selector(query_conditions(parse_query("topic /a"))) == {"topic": "/a"}
    assert to_selector(query_conditions(parse_query(""))) == {}
