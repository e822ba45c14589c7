"""The spool's bound and its policy per topic when full (no ROS, no database): kept topics stay
whole, the droppable topics lose their oldest messages first, every loss is counted per topic."""
import pytest
from nav_msgs.msg import Odometry
from ros_mongo_samples import serialized
from sensor_msgs.msg import Image

from ros_mongo import TopicInfo, make_record
from ros_mongo.errors import SpoolError
from ros_mongo.recording.bounded_spool import BoundedSpool, DropPolicy
from ros_mongo.recording.spool import SpoolFull
from ros_mongo.records import split_time

ODOM = TopicInfo.of_class("/odom", Odometry)
IMAGE = TopicInfo.of_class("/camera/rgb/image_raw", Image)
INFOS = {(i.topic, i.msg_type, i.md5sum, i.callerid): i for i in (ODOM, IMAGE)}
PIXELS = bytes(range(256)) * 400  # 100 KB


def odom(index):
    msg = Odometry()
    msg.header.frame_id = str(index)
    return make_record("/odom", Odometry, serialized(msg), receive=split_time(100 + index),
                       robot_id="r1")


def image(index):
    msg = Image(height=100, width=1000, encoding="mono8", step=1000, data=PIXELS)
    msg.header.frame_id = str(index)
    return make_record(IMAGE.topic, Image, serialized(msg), receive=split_time(100 + index),
                       robot_id="r1")


def drain(spool):
    """Every entry a drain would store, in drain order, committing as it goes."""
    entries = []
    while spool.pending:
        batch, token = spool.read(max_entries=7)
        entries += batch
        spool.commit(token, sum(not isinstance(e, TopicInfo) for e in batch))
    return entries


def test_a_full_spool_drops_the_oldest_images_first_and_counts_each(tmp_path):
    limit = 2_000_000  # the odometry (about 1 MB with its spool headers) and a few images
    spool = BoundedSpool(tmp_path / "s.spool", max_bytes=limit, min_free_bytes=0,
                         segment_bytes=250_000).open()
    for index in range(40):  # an outage: 40 images (4 MB) and 400 odometry messages arrive
        spool.append([image(index)] + [odom(10 * index + k) for k in range(10)], INFOS)
        assert spool.size <= limit
    dropped = spool.dropped[IMAGE.topic]
    assert set(spool.dropped) == {IMAGE.topic} and 20 <= dropped <= 38  # only images, counted
    entries = drain(spool)
    spool.close()
    odometry = [int(e.fields["header"]["frame_id"]) for e in entries if e.topic == "/odom"
                and not isinstance(e, TopicInfo)]
    images = [int(e.fields["header"]["frame_id"]) for e in entries if e.topic == IMAGE.topic
              and not isinstance(e, TopicInfo)]
    assert odometry == list(range(400))                    # every odometry message, in order
    assert images == list(range(40 - len(images), 40))     # the newest images, in order
    assert len(images) + dropped == 40                     # what is missing is exactly what was counted
    # each file's messages are preceded by their topic's info (a later recorder may drain it)
    first_image = next(i for i, e in enumerate(entries) if e.topic == IMAGE.topic)
    assert isinstance(entries[first_image], TopicInfo)


def test_kept_topics_are_refused_whole_once_no_droppable_data_is_left(tmp_path):
    spool = BoundedSpool(tmp_path / "s.spool", max_bytes=300_000, min_free_bytes=0).open()
    spool.append([image(0), image(1)], INFOS)
    records = [odom(i) for i in range(400)]  # about 300 KB with the images gone
    with pytest.raises(SpoolFull, match="holds no droppable"):
        for start in range(0, 400, 50):
            spool.append(records[start:start + 50], INFOS)
    assert spool.dropped == {IMAGE.topic: 2}  # the images went first, counted
    kept = [e for e in drain(spool) if not isinstance(e, TopicInfo)]
    assert [int(e.fields["header"]["frame_id"]) for e in kept] == list(range(len(kept)))
    assert 0 < len(kept) < 400 and len(kept) % 50 == 0  # whole batches only: the refused one is not written
    spool.close()


def test_a_new_recorder_drains_what_an_earlier_one_left(tmp_path):
    spool = BoundedSpool(tmp_path / "s.spool", max_bytes=10_000_000, min_free_bytes=0,
                         segment_bytes=200_000).open()
    spool.append([odom(0), image(0), image(1), image(2), odom(1)], INFOS)
    spool.close()
    again = BoundedSpool(tmp_path / "s.spool", max_bytes=10_000_000, min_free_bytes=0,
                         segment_bytes=200_000).open()
    assert again.pending_records == 5
    entries = drain(again)
    assert [(e.topic, e.fields["header"]["frame_id"]) for e in entries if not isinstance(e, TopicInfo)] \
        == [("/odom", "0"), ("/odom", "1")] + [(IMAGE.topic, str(i)) for i in range(3)]
    assert sum(isinstance(e, TopicInfo) for e in entries) >= 2
    assert sorted(p.name for p in tmp_path.iterdir() if ".drop." in p.name) <= ["s.spool.drop.00000002",
                                                                                  "s.spool.drop.00000002.offset"]
    again.close()
    with pytest.raises(SpoolError, match="in use"):  # one recorder per spool
        other = BoundedSpool(tmp_path / "s.spool").open()
        BoundedSpool(tmp_path / "s.spool").open()
    other.close()


def test_the_policy_names_types_and_topic_patterns():
    policy = DropPolicy(["sensor_msgs/Image"], ["^/debug/"])
    assert policy.droppable("/camera/rgb/image_raw", "sensor_msgs/Image")
    assert policy.droppable("/debug/cloud", "sensor_msgs/PointCloud2")
    assert not policy.droppable("/scan", "sensor_msgs/LaserScan")
    assert not DropPolicy([], []).droppable("/camera", "sensor_msgs/Image")
