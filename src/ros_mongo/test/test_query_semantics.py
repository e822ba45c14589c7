"""One query suite, run on both real servers: every supported field operator gives the answer the
semantics in ros_mongo.storage.documents define (missing fields, scalars against arrays, nulls, types,
the "NaN"/"Infinity" encodings). The expected answers are written by hand from those rules."""
import math

import genpy
import pytest
from sensor_msgs.msg import JointState, LaserScan
from std_msgs.msg import String

from ros_mongo import open_store
from ros_mongo.query import Query

pytestmark = pytest.mark.db


def _messages():
    """(topic, message) #0..#5; the comments say what the decoded fields hold."""
    def scan(range_max, ranges, frame, angle_min):
        msg = LaserScan(range_max=range_max, ranges=ranges, angle_min=angle_min)
        msg.header.frame_id = frame
        return msg
    joints = JointState(name=["a", "b"], position=[1.0])
    joints.header.frame_id = "laser"
    return [
        ("/scan", scan(1.5, [1.0, 2.0, 3.0], "laser", -1.0)),     # 0
        ("/scan", scan(math.nan, [4.0], "x", 0.0)),               # 1: range_max "NaN"
        ("/scan", scan(math.inf, [], "", 1.0)),                   # 2: range_max "Infinity"
        ("/scan", scan(-math.inf, [1.0], "laser", 2.0)),          # 3: range_max "-Infinity"
        ("/chatter", String(data="1")),                           # 4: no range_max, no header
        ("/joint_states", joints),                                # 5: no range_max
    ]


CASES = [
    ({"range_max": {"$gt": 0}}, [0, 2]),                      # +Infinity is above every number
    ({"range_max": {"$lt": 0}}, [3]),
    ({"range_max": [-10, 10]}, [0]),                          # NaN is in no range
    ({"range_max": {"$gte": -1e308}}, [0, 2]),
    ({"range_max": 1.5}, [0]),
    ({"range_max": {"$ne": 1.5}}, [1, 2, 3, 4, 5]),           # a missing field is "not equal"
    ({"range_max": {"$exists": True}}, [0, 1, 2, 3]),
    ({"range_max": {"$exists": False}}, [4, 5]),
    ({"range_max": "NaN"}, [1]),                              # the stored encoding itself
    ({"ranges": 1.0}, [0, 3]),                                # a scalar against an array: an element
    ({"ranges": {"$ne": 1.0}}, [1, 2, 4, 5]),
    ({"ranges": {"$in": [4.0, 9.0]}}, [1]),
    ({"ranges": {"$nin": [1.0, 4.0]}}, [2, 4, 5]),
    ({"ranges": {"$gt": 2.5}}, [0, 1]),                       # an element in range
    ({"ranges": [1.5, 2.5]}, [0]),                            # one element meets both bounds
    ({"ranges": {"$gt": 3.5, "$lt": 1.5}}, []),               # ... never two different elements
    ({"header.frame_id": "laser"}, [0, 3, 5]),
    ({"header.frame_id": {"$nin": ["laser", "x"]}}, [2, 4]),
    ({"header.frame_id": {"$gte": "l"}}, [0, 1, 3, 5]),       # strings compare with strings
    ({"data": "1"}, [4]),
    ({"data": 1}, []),                                        # 1 is not "1"
    ({"data": {"$gt": 0}}, []),                               # nor in a numeric range
    ({"name": "b"}, [5]),
    ({"angle_min": {"$gt": -0.5, "$lt": 1.5}}, [1, 2]),
    ({"range_max": None}, [4, 5]),                            # null: missing (or null)
    ({"range_max": {"$ne": None}}, [0, 1, 2, 3]),
    ({"header.frame_id": {"$in": []}}, []),
    ({"header.frame_id": {"$nin": []}}, [0, 1, 2, 3, 4, 5]),
]


@pytest.fixture
def filled(db_url):
    with open_store(db_url) as store:
        for i, (topic, msg) in enumerate(_messages()):
            store.insert_message(topic, msg, receive_time=1_700_000_000 + i)
        yield store


def _indices(store, fields, **options):
    return [int(m.receive_time) - 1_700_000_000 for m in store.find(Query.build(fields=fields), **options)]


def test_every_operator_means_the_same_on_both_backends(filled):
    failures = []
    for fields, expected in CASES:
        got = _indices(filled, fields)
        count = filled.count(Query.build(fields=fields))
        if got != expected or count != len(expected):
            failures.append(f"{fields}: got {got} (count {count}), expected {expected}")
    assert not failures, "\n".join(failures)


def test_newest_first_and_limits_apply_after_the_conditions(filled):
    assert _indices(filled, {"range_max": {"$exists": True}}, newest_first=True, limit=3) == [3, 2, 1]
    assert _indices(filled, {"ranges": 1.0}, limit=1) == [0]


def test_field_conditions_combine_with_topic_type_and_time(filled):
    query = Query.build(topic=["/scan", "/joint_states"], start_time=1_700_000_001,
                        fields={"header.frame_id": "laser"})
    assert [int(m.receive_time) - 1_700_000_000 for m in filled.find(query)] == [3, 5]
    query = Query.build(msg_type="sensor_msgs/LaserScan", fields={"ranges": {"$ne": 1.0}})
    assert [int(m.receive_time) - 1_700_000_000 for m in filled.find(query)] == [1, 2]


def test_an_array_element_by_index(filled, request):
    if "mongodb" in request.node.callspec.id:
        pytest.xfail("nx-27017 does not resolve numeric path components (mongod does: "
                     "'msg.ranges.0' is the first element)")
    assert _indices(filled, {"ranges.0": 1.0}) == [0, 3]


@pytest.mark.parametrize("fields", [{"x": {"$gt": True}}, {"x": [0, "z"]}, {"x": {"$lt": None}},
                                    {"x": {"$gte": 1, "$lte": "9"}}])
def test_ranges_over_mixed_or_unordered_types_are_refused(fields):
    with pytest.raises(Exception, match="range bounds must all be numbers or all strings"):
        Query.build(fields=fields)


def test_time_only_queries_are_unchanged(filled):
    stamp = genpy.Time(1_700_000_002, 0).to_sec()
    assert [int(m.receive_time) - 1_700_000_000 for m in filled.find(Query.build(start_time=stamp))] == \
        [2, 3, 4, 5]


@pytest.fixture
def authored(db_url):
    """#0 by ServiceRobot (lidar), #1 by Alice (lidar), #2 without an author (odom)."""
    from ros_mongo import TopicInfo, make_record
    from ros_mongo.records import split_time

    with open_store(db_url) as store:
        store.put_topic(TopicInfo.of_class("/scan", LaserScan))
        store.put_topic(TopicInfo.of_class("/odom", String))
        records = []
        for i, (topic, cls, tag, author) in enumerate([("/scan", LaserScan, "lidar", "ServiceRobot"),
                                                       ("/scan", LaserScan, "lidar", "Alice"),
                                                       ("/odom", String, "odom", None)]):
            raw = _serialized(cls())
            records.append(make_record(topic, cls, raw, receive=split_time(1_700_000_000 + i), tags=[tag],
                                       author=author))
        store.insert_records(records)
        yield store


def _serialized(msg):
    from io import BytesIO
    buffer = BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


@pytest.mark.parametrize("text, expected", [
    ("author ServiceRobot", [0]),                     # the original README's example 1
    ("author Alice", [1]),
    ("author Nobody", []),
    ("tags lidar", [0, 1]),                           # the original README's example 2
    ("tags:lidar", [0, 1]),
    ("tags=odom", [2]),
    ("author ServiceRobot tags odom", [0]),           # words after the first two are ignored
    ("{author: Alice, tags: [lidar]}", [1]),
    ("{author: Alice, tags: [odom]}", []),
])
def test_original_query_forms_mean_the_same_on_both_backends(authored, text, expected):
    from ros_mongo.query import parse_query

    query = parse_query(text)
    got = [int(m.receive_time) - 1_700_000_000 for m in authored.find(query)]
    assert got == expected
    assert authored.count(query) == len(expected)
    assert [m.author for m in authored.find(query)] == [["ServiceRobot", "Alice", None][i] for i in expected]
