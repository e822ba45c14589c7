"""The storage library against the real servers (pouchdb-server and nx-27017), both backends."""
import socket

import pytest
from nav_msgs.msg import Odometry
from ros_mongo_samples import (
    _header,
    custom_class,
    custom_message,
    image,
    joints,
    odometry,
    scan,
    serialized,
)
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import String

from ros_harness import http_get_json
from ros_mongo import (
    QueryError,
    StoreError,
    StoreUnavailable,
    TopicInfo,
    UnknownTypeError,
    make_record,
    open_store,
)
from ros_mongo.records import split_time

pytestmark = pytest.mark.db

@pytest.mark.parametrize("topic,make", [
    ("/odom", odometry), ("/camera/rgb/image_raw", image), ("/scan", scan),
    ("/joint_states", joints), ("/detections", custom_message)])
def test_round_trip_keeps_bytes_and_metadata(db_url, topic, make):
    msg = make()
    with open_store(db_url) as store:
        doc_id = store.insert_message(topic, msg, tags=["a", "b"], receive_time=1234.5,
                                      session_id="s1", robot_id="r1")
    with open_store(db_url) as store:  # a fresh store: nothing cached
        [stored] = list(store.find_messages(topic=topic))
        assert stored.id == doc_id
        assert stored.raw == serialized(msg)
        assert (stored.msg_type, stored.md5sum) == (msg._type, msg._md5sum)
        assert stored.receive_time == 1234.5 and stored.tags == ["a", "b"]
        assert (stored.session_id, stored.robot_id) == ("s1", "r1")
        assert stored.header_stamp == pytest.approx(msg.header.stamp.to_sec())
        again = stored.message()
        assert serialized(again) == serialized(msg)
        assert again.header.frame_id == msg.header.frame_id
        [info] = store.topics()
        assert (info.topic, info.msg_type, info.definition) == (topic, msg._type, msg._full_text)


def test_decoded_fields_are_stored_and_safe(db_url):
    with open_store(db_url) as store:
        store.insert_message("/scan", scan())
        store.insert_message("/camera/rgb/image_raw", image())
        fields = {m.topic: m.fields for m in store.find_messages()}
    assert fields["/scan"]["ranges"][3] == "Infinity" and fields["/scan"]["ranges"][5] == "NaN"
    assert fields["/scan"]["header"]["frame_id"] == "laser"
    assert fields["/camera/rgb/image_raw"]["encoding"] == "rgb8"
    assert fields["/camera/rgb/image_raw"]["step"] == 192
    assert fields["/camera/rgb/image_raw"]["data"] is None  # bytes only in raw


def _fill(store):
    for i in range(10):
        store.insert_message("/odom", odometry(x=0.5 * i, frame="odom" if i % 2 else "map"),
                             receive_time=100.0 + i, tags=["odom"] + (["even"] if i % 2 == 0 else []),
                             session_id="s1" if i < 5 else "s2", robot_id="r1")
    store.insert_message("/chatter", String(data="hello"), receive_time=104.5, tags=["even"])


def _times(messages):
    return [m.receive_time for m in messages]


def test_queries(db_url):
    with open_store(db_url) as store:
        _fill(store)
        assert _times(store.find_messages(topic="/odom", start_time=102, end_time=104)) == [102, 103, 104]
        assert _times(store.find_messages(tags=["even"])) == [100, 102, 104, 104.5, 106, 108]
        assert _times(store.find_messages(tags=["even", "odom"], session_id="s2")) == [106, 108]
        assert _times(store.find_messages(msg_type="std_msgs/String")) == [104.5]
        assert _times(store.find_messages(fields={"header.frame_id": "map"})) == [100, 102, 104, 106, 108]
        x_range = {"pose.pose.position.x": {"$gte": 1.0, "$lt": 2.5}}
        assert _times(store.find_messages(topic="/odom", fields=x_range)) == [102, 103, 104]
        assert _times(store.find_messages(fields={"pose.pose.position.x": [3.5, 99]})) == [107, 108, 109]
        assert _times(store.find_messages(newest_first=True, limit=3)) == [109, 108, 107]
        assert _times(store.find_messages(topic=["/chatter", "/odom"], start_time=104, limit=3)) == \
            [104, 104.5, 105]
        assert store.count_messages(topic="/odom", robot_id="r1") == 10
        assert store.count_messages(session_id="nobody") == 0


def test_large_binary_goes_to_attachments_or_gridfs(db_url):
    size = 9_000_000  # above CouchDB's 8,000,000-byte document limit
    cloud = PointCloud2(header=_header(1, "velodyne"), height=1, width=size // 16,
                        fields=[PointField("x", 0, PointField.FLOAT32, 1)], point_step=16,
                        row_step=size, data=bytes(size), is_dense=True)
    with open_store(db_url) as store:
        doc_id = store.insert_message("/points", cloud)
        [stored] = list(store.find_messages(topic="/points"))
        assert stored.raw == serialized(cloud)
        if store.backend == "couchdb":
            doc = http_get_json(f"{db_url}/{doc_id}")
            assert "raw" not in doc and doc["_attachments"]["raw"]["length"] == len(stored.raw)
            assert len(str(doc)) < 100_000
        else:
            doc = store.messages.find_one({"_id": doc_id})
            assert "raw" not in doc and doc["blob"] is True
            assert store.db["blobs.files"].find_one({"_id": doc_id})["length"] == len(stored.raw)


def test_repeated_records_are_stored_once(db_url):
    with open_store(db_url) as store:
        store.put_topic(TopicInfo.of_class("/odom", Odometry))
        records = [make_record("/odom", Odometry, serialized(odometry(x=i)), receive=split_time(10 + i))
                   for i in range(5)]
        assert store.insert_records(records[:3]) == 3
        assert store.insert_records(records) == 2  # a retry after an unknown outcome
        assert store.count() == 5


def test_custom_type_from_stored_definition_only(db_url):
    msg = custom_message()
    with open_store(db_url) as store:
        store.insert_message("/detections", msg)
        stored = next(store.find_messages(topic="/detections"))
        decoded = stored.message()
    assert decoded.label == "mug" and decoded.corners[1].y == 0.5
    assert decoded.__class__ is not msg.__class__  # built from the definition in the database


def test_unknown_type_without_definition(db_url):
    record = make_record("/mystery", custom_class(), serialized(custom_message()))
    record.msg_type, record.md5sum = "nowhere_msgs/Thing", "0" * 32
    with open_store(db_url) as store:
        store.insert_records([record])
        stored = next(store.find_messages(topic="/mystery"))
        assert stored.raw  # the bytes are kept even though the type is unknown
        with pytest.raises(UnknownTypeError, match="nowhere_msgs/Thing.*not installed"):
            stored.message()


@pytest.mark.parametrize("criteria,match", [
    (dict(fields={"pose.x": {"$regexx": "a"}}), "unknown operator '\\$regexx'"),
    (dict(fields={"pose..x": 1}), "bad field path"),
    (dict(fields={"pose.x": [1, 2, 3]}), "must be \\[low, high\\]"),
    (dict(fields={"pose.x": {"$in": 5}}), "\\$in needs a list"),
    (dict(start_time=10, end_time=5), "start_time 10.0 is after end_time 5.0"),
    (dict(start_time="yesterday"), "start_time must be a finite number"),
    (dict(topic=["/odom", 3]), "topic must be a string or a list"),
    (dict(limit=-1), "limit must be a non-negative integer"),
])
def test_malformed_queries_are_clear(db_url, criteria, match):
    with open_store(db_url) as store:
        with pytest.raises(QueryError, match=match):
            list(store.find_messages(**criteria))


def test_unreachable_server_and_bad_urls():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # bound but not listening: connections are refused
        for url in (f"http://127.0.0.1:{port}/robot_data", f"mongodb://127.0.0.1:{port}/robot_data"):
            with pytest.raises(StoreUnavailable, match="unreachable"):
                open_store(url, timeout=1.0)
    with pytest.raises(StoreError, match="unsupported database URL scheme 'ftp'"):
        open_store("ftp://host/db")
    with pytest.raises(StoreError, match="bad CouchDB database name"):
        open_store("http://127.0.0.1:5984/Robot Data", connect=False)


def test_credentials_never_shown():
    store = open_store("http://alice:s3cret@127.0.0.1:9/robot_data", connect=False, timeout=0.5)
    assert "s3cret" not in repr(store) and "alice:***@" in store.url
    with pytest.raises(StoreUnavailable) as err:
        store.ping()
    assert "s3cret" not in str(err.value)


def test_blob_document_of_the_previous_version_still_loads_and_is_not_written_again(couchdb_url):
    """The previous version wrote attachment documents with a server-made revision (plain
    `_bulk_docs`); they load as before, and a retry of the same record leaves them alone."""
    import base64

    import requests

    big = image(width=400, height=300)  # 360,000 bytes of pixels: above the blob threshold
    raw = serialized(big)
    record = make_record("/camera/rgb/image_raw", big.__class__, raw, receive=split_time(20.5),
                         session_id="old", robot_id="r1")
    old_form = {"_id": record.id, "kind": "message", "topic": "/camera/rgb/image_raw",
                "type": "sensor_msgs/Image", "md5sum": big.__class__._md5sum, "receive_time": 20.5,
                "receive_secs": 20, "receive_nsecs": 500000000, "header_stamp": 1.0, "tags": [],
                "session_id": "old", "robot_id": "r1", "callerid": "", "size": len(raw),
                "msg": {"height": 300, "width": 400, "encoding": "rgb8", "data": None},
                "_attachments": {"raw": {"content_type": "application/octet-stream",
                                         "data": base64.b64encode(raw).decode()}}}
    with open_store(couchdb_url) as store:
        store.put_topic(TopicInfo.of_class("/camera/rgb/image_raw", big.__class__, robot_id="r1"))
        answer = requests.post(f"{couchdb_url}/_bulk_docs", json={"docs": [old_form]}, timeout=30)
        assert answer.status_code == 201 and "error" not in answer.json()[0]
        rev = answer.json()[0]["rev"]
        [stored] = list(store.find_messages(session_id="old"))
        assert stored.raw == raw and stored.fields["width"] == 400
        assert store.insert_records([record]) == 0  # already there: not written again
    doc = http_get_json(f"{couchdb_url}/{record.id}?conflicts=true")
    assert doc["_rev"] == rev and "_conflicts" not in doc


def test_blob_documents_are_stored_once_without_conflicts(couchdb_url):
    big = image(width=400, height=300)
    records = [make_record("/camera/rgb/image_raw", big.__class__, serialized(big),
                           receive=split_time(30 + i)) for i in range(3)]
    with open_store(couchdb_url) as store:
        store.put_topic(TopicInfo.of_class("/camera/rgb/image_raw", big.__class__))
        assert store.insert_records(records[:2]) == 2
        assert store.insert_records(records) == 1  # a retry after an unknown outcome
        assert [m.raw for m in store.find_messages(topic="/camera/rgb/image_raw")] == [r.raw for r in records]
    for record in records:
        doc = http_get_json(f"{couchdb_url}/{record.id}?conflicts=true&revs_info=true")
        assert "_conflicts" not in doc and [i["rev"] for i in doc["_revs_info"]] == [doc["_rev"]]


def test_images_written_without_a_lookup_go_binary_and_are_stored_once_however_often_sent(couchdb_url):
    """The recorder's writes (`look_up=False`): one multipart PUT per image with its bytes as they
    are, the revision given. Sent again: no second revision, no conflict, no new change in the
    feed; deleted meanwhile: stays deleted. Readers get the same bytes."""
    import requests

    big = image(width=400, height=300)  # 360,000 bytes of pixels: above the blob threshold
    raw = serialized(big)
    records = [make_record("/camera/rgb/image_raw", big.__class__, raw, receive=split_time(40 + i))
               for i in range(3)]
    with open_store(couchdb_url) as store:
        store.put_topic(TopicInfo.of_class("/camera/rgb/image_raw", big.__class__))
        [(_, _, weight)] = store.prepare_records(records[:1]).items
        assert len(raw) < weight < len(raw) + 2000  # base64 would be 480,000 bytes and more
        assert store.insert_records(records, look_up=False) == 3
        doc = http_get_json(f"{couchdb_url}/{records[2].id}")
        requests.delete(f"{couchdb_url}/{records[2].id}", params={"rev": doc["_rev"]},
                        timeout=30).raise_for_status()
        since = http_get_json(f"{couchdb_url}/_changes")["last_seq"]
        assert store.insert_records(records, look_up=False) == 3  # sent again: counted, not stored
        changes = requests.get(f"{couchdb_url}/_changes", params={"since": since}, timeout=30).json()
        assert changes["results"] == []
        assert [m.raw for m in store.find_messages(topic="/camera/rgb/image_raw")] == [raw, raw]
    for record in records[:2]:
        doc = http_get_json(f"{couchdb_url}/{record.id}?conflicts=true&revs_info=true")
        assert "_conflicts" not in doc and [i["rev"] for i in doc["_revs_info"]] == [doc["_rev"]]
        assert doc["_attachments"]["raw"]["length"] == len(raw) and "raw" not in doc
    assert requests.get(f"{couchdb_url}/{records[2].id}", timeout=30).status_code == 404


def test_while_multipart_writes_are_off_images_go_base64_with_the_same_revision(couchdb_url):
    """The fallback after a multipart write got no answer (a cluster with a node down): the same
    documents through `_bulk_docs`, so a message sent both ways is still stored once."""
    from ros_mongo.storage.couch import message_rev

    big = image(width=400, height=300)
    raw = serialized(big)
    records = [make_record("/camera/rgb/image_raw", big.__class__, raw, receive=split_time(50 + i))
               for i in range(2)]
    with open_store(couchdb_url) as store:
        store.put_topic(TopicInfo.of_class("/camera/rgb/image_raw", big.__class__))
        assert store.insert_records(records[:1], look_up=False) == 1  # multipart
        store._multipart_off_until = float("inf")
        [(_, _, weight)] = store.prepare_records(records[:1]).items
        assert weight > len(raw) * 4 / 3  # base64 inside the JSON
        assert store.insert_records(records, look_up=False) == 2
        assert [m.raw for m in store.find_messages(topic="/camera/rgb/image_raw")] == [raw, raw]
    for record in records:
        doc = http_get_json(f"{couchdb_url}/{record.id}?conflicts=true&revs_info=true")
        assert [i["rev"] for i in doc["_revs_info"]] == [message_rev(record.id)] and "_conflicts" not in doc
