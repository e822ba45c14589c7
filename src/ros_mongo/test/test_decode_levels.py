"""~decode per topic or type (full | index | raw) through the recorder core, on both real servers
(pouchdb-server, nx-27017): what each level makes queryable, and that the bytes are always whole."""
import genpy
import pytest
from nav_msgs.msg import Odometry
from ros_mongo_samples import serialized
from sensor_msgs.msg import Image, LaserScan

from ros_mongo import open_store
from ros_mongo.messages.decoding import DecodePolicy
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.recorder import Recorder
from ros_mongo.records import split_time

N = 6


def _odom(i):
    msg = Odometry()
    msg.header.stamp, msg.header.frame_id = genpy.Time(50 + i, 250), "odom"
    msg.pose.pose.position.x = float(i)
    msg.pose.covariance = [float(i)] * 36
    return msg


def _scan(i):
    msg = LaserScan(angle_min=-1.0, angle_max=1.0, range_max=10.0 + i, ranges=[float(i)] * 5)
    msg.header.stamp, msg.header.frame_id = genpy.Time(60 + i, 0), f"laser{i}"
    return msg


def _image(i):
    msg = Image(height=2, width=3 + i, encoding="mono8", step=3 + i, data=bytes(range(2 * (3 + i))))
    msg.header.stamp, msg.header.frame_id = genpy.Time(70 + i, 125), f"cam{i}"
    return msg


@pytest.mark.db
def test_each_decode_level_keeps_its_fields_queryable_on_both_backends(db_url, tmp_path):
    policy = DecodePolicy({"/scan": "index", "sensor_msgs/Image": "raw"}, default="full")
    sent = {}
    with open_store(db_url) as store:
        spool = BoundedSpool(tmp_path / "rec.spool", min_free_bytes=0).open()
        recorder = Recorder(store, spool, batch_period=0.05, decode=policy).start()
        for i in range(N):
            for topic, msg in (("/odom", _odom(i)), ("/scan", _scan(i)), ("/camera", _image(i))):
                raw = serialized(msg)
                sent[(topic, i)] = raw
                recorder.receive(topic, raw, split_time(1000 + i + 0.1 * len(topic)), msg._type,
                                 msg._md5sum, msg._full_text)
        counts = recorder.stop(timeout=60)
        spool.close()
        assert counts["stored"] == 3 * N and counts["dropped"] == 0

        def xs(**criteria):
            return [m.fields for m in store.find_messages(**criteria)]

        # full: every field, arrays included
        got = list(store.find_messages(topic="/odom", fields={"pose.pose.position.x": [2.0, 4.0]}))
        assert [m.fields["pose"]["pose"]["position"]["x"] for m in got] == [2.0, 3.0, 4.0]
        assert len(xs(topic="/odom", fields={"pose.covariance": 5.0})) == 1
        # index: scalars and the header, no arrays
        got = list(store.find_messages(topic="/scan", fields={"range_max": {"$gte": 13.0}}))
        assert [m.fields["header"]["frame_id"] for m in got] == ["laser3", "laser4", "laser5"]
        assert xs(topic="/scan", fields={"header.frame_id": "laser1"})[0]["angle_max"] == 1.0
        assert xs(topic="/scan", fields={"ranges": 2.0}) == []          # arrays are not decoded
        assert all("ranges" not in f for f in xs(topic="/scan"))
        # raw: no fields, but the metadata and the header stamp are queryable
        assert xs(topic="/camera", fields={"width": 4}) == []
        images = list(store.find_messages(topic="/camera", start_time=1003.0))
        assert [m.header_stamp for m in images] == [73.000000125, 74.000000125, 75.000000125]
        assert all(m.fields is None for m in images)
        # every level keeps the exact bytes and decodes back
        for m in store.find_messages():
            index = int(round(m.receive_time - 1000 - 0.1 * len(m.topic)))
            assert m.raw == sent[(m.topic, index)]
        assert next(store.find_messages(topic="/camera", limit=1)).message().width == 3
