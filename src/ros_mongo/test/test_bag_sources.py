"""Several publishers, bags and robots in one database: each keeps its own connection header, ids
never collide, imports are idempotent, and import memory is bounded by bytes (both backends)."""
import genpy
import pytest
import rosbag
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import Image
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ros_mongo import open_store
from ros_mongo.files.bagio import export_bag, import_bag, iter_bag
from ros_mongo.query import Query
from ros_mongo.records import TopicInfo, make_record, new_message_id

pytestmark = pytest.mark.db

T0 = 1_700_000_000


def _header(msg_class, topic, callerid, latching):
    return {"topic": topic, "type": msg_class._type, "md5sum": msg_class._md5sum,
            "message_definition": msg_class._full_text, "callerid": callerid,
            "latching": "1" if latching else "0"}


def write_multi_publisher_bag(path, publishers, offset=0):
    """/tf from several publishers, one bag connection each. rosbag's Python writer keeps one
    connection per topic, so its current connection is dropped before another publisher's first
    message (a bag recorded by `rosbag record` has one connection per publisher the same way)."""
    with rosbag.Bag(str(path), "w") as bag:
        connections = {}
        for i in range(30):
            callerid, latching = publishers[i % len(publishers)]
            frame = TransformStamped()
            frame.header.stamp = genpy.Time(T0 + offset + i, 0)
            frame.child_frame_id = f"{callerid}_{i}"
            frame.transform.rotation.w = 1.0
            if callerid in connections:
                bag._topic_connections["/tf"] = connections[callerid]
            else:
                bag._topic_connections.pop("/tf", None)
            bag.write("/tf", TFMessage(transforms=[frame]), genpy.Time(T0 + offset + i, 0),
                      connection_header=_header(TFMessage, "/tf", callerid, latching))
            connections[callerid] = bag._topic_connections["/tf"]
            bag._topic_connections.pop("/tf", None)
            bag.write("/chatter", String(data=f"{callerid} {i}"), genpy.Time(T0 + offset + i, 5),
                      connection_header=_header(String, "/chatter", "/talker", False))


def per_connection(path):
    """{(topic, callerid, latching): [(bag time ns, bytes), ...]} of a bag."""
    out = {}
    for topic, raw, stamp, header in iter_bag(path):
        key = (topic, header.get("callerid", ""), header.get("latching", "0"))
        out.setdefault(key, []).append((stamp.to_nsec(), raw))
    return out


def test_publishers_bags_and_robots_round_trip_exactly(db_url, tmp_path):
    alpha, beta = tmp_path / "alpha.bag", tmp_path / "beta.bag"
    write_multi_publisher_bag(alpha, [("/robot_state_publisher", True), ("/odom_node", False)])
    write_multi_publisher_bag(beta, [("/robot_state_publisher", False), ("/amcl", False)], offset=1000)
    assert len(per_connection(alpha)) == 3  # the source bag really has two /tf connections
    with open_store(db_url) as store:
        import_bag(alpha, store, robot_id="alpha", progress=False)
        import_bag(beta, store, robot_id="beta", progress=False)
        infos = {(i.topic, i.callerid, i.latching, i.robot_id) for i in store.topics()}
        assert ("/tf", "/robot_state_publisher", True, "alpha") in infos
        assert ("/tf", "/robot_state_publisher", False, "beta") in infos
        for name, source in (("alpha", alpha), ("beta", beta)):
            out = tmp_path / f"{name}_out.bag"
            export_bag(store, Query.build(robot_id=name), out, progress=False)
            assert per_connection(out) == per_connection(source)


def test_import_with_topics_then_whole_and_again_under_another_name_stores_once(db_url, tmp_path):
    bag = tmp_path / "run.bag"
    write_multi_publisher_bag(bag, [("/a", False), ("/b", False)])
    renamed = tmp_path / "renamed_copy.bag"
    renamed.write_bytes(bag.read_bytes())
    with open_store(db_url) as store:
        assert import_bag(bag, store, topics=["/chatter"], progress=False).messages == 30
        assert import_bag(bag, store, progress=False).messages == 60
        assert store.count() == 60
        import_bag(renamed, store, progress=False)
        import_bag(bag, store, topics=["/tf"], progress=False)
        assert store.count() == 60


def test_import_holds_a_bounded_number_of_bytes(db_url, tmp_path):
    bag = tmp_path / "clouds.bag"
    size, count = 512 * 1024, 32  # above the blob threshold: attachments / GridFS
    with rosbag.Bag(str(bag), "w") as out:
        for i in range(count):
            image = Image(height=512, width=1024, encoding="mono8", step=1024,
                          data=bytes([i]) * size)
            out.write("/cloud", image, genpy.Time(T0 + i, 0))
    batch_bytes = 1024 * 1024
    with open_store(db_url) as store:
        result = import_bag(bag, store, batch_bytes=batch_bytes, progress=False)
        assert result.messages == count and store.count() == count
        stored = [m.raw for m in store.find(Query())]
    # at most three batches at once, each closing at the first message past batch_bytes
    message_bytes = len(stored[0])
    assert 0 < result.peak_batch_bytes <= 3 * (batch_bytes + message_bytes)
    assert result.peak_batch_bytes < result.bytes / 2
    assert [raw[-size:] for raw in stored] == [bytes([i]) * size for i in range(count)]


def test_two_robots_never_produce_the_same_id_or_topic_document(db_url):
    stamp = genpy.Time(T0, 123)
    raw = b"\x02\x00\x00\x00hi"
    records = [make_record("/chatter", String, raw, receive=stamp, robot_id=robot,
                           record_id=new_message_id(stamp.secs, stamp.nsecs, robot, token="000000000000"))
               for robot in ("robot-1", "robot/1", "robot_1")]
    assert len({r.id for r in records}) == 3
    assert all(r.id.startswith(f"{T0 * 10**9 + 123:019d}-") for r in records)
    infos = [TopicInfo.of_class("/chatter", String, callerid="/talker", robot_id=r.robot_id) for r in records]
    assert len({i.id for i in infos}) == 3
    with open_store(db_url) as store:
        for info in infos:
            store.put_topic(info)
        assert store.insert_records(records) == 3
        assert sorted(m.robot_id for m in store.find(Query())) == ["robot-1", "robot/1", "robot_1"]
        assert sorted(i.robot_id for i in store.topics()) == ["robot-1", "robot/1", "robot_1"]
