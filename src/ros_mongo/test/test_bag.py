"""Bag -> database -> bag, byte for byte, on both backends; the command-line tool and its errors."""
import re
import subprocess
import sys

import genpy
import pytest
import rosbag
from nav_msgs.msg import Odometry
from ros_mongo_samples import custom_message
from sensor_msgs.msg import Image, JointState, LaserScan
from std_msgs.msg import Header

from ros_harness import wait_until
from ros_mongo import BagError, open_store, parse_query
from ros_mongo.bagio import export_bag, import_bag, iter_bag

pytestmark = pytest.mark.db


def write_bag(path):
    """A bag with the four original types (one image above the blob threshold) and a custom type."""
    t0 = 1_700_000_000
    detection = custom_message()
    detection_header = {"topic": "/detections", "type": detection._type, "md5sum": detection._md5sum,
                        "message_definition": detection._full_text, "callerid": "/detector", "latching": "1"}
    with rosbag.Bag(str(path), "w") as bag:
        for i in range(30):
            stamp = genpy.Time(t0 + i // 10, (i % 10) * 100_000_000 + 7)
            header = Header(seq=i, stamp=stamp, frame_id="base_link")
            odom = Odometry(header=header, child_frame_id="base_link")
            odom.pose.pose.position.x, odom.pose.pose.orientation.w = 0.1 * i, 1.0
            bag.write("/odom", odom, stamp)
            if i % 3 == 0:
                scan = LaserScan(header=header, ranges=[float(i)] * 1081)
                bag.write("/scan", scan, stamp + genpy.Duration(0, 1000))
                bag.write("/joint_states", JointState(header=header, name=["a"], position=[0.1 * i]),
                          stamp + genpy.Duration(0, 2000))
            if i % 10 == 0:
                width, height = (640, 480) if i == 10 else (32, 24)  # 640x480: attachment / GridFS
                data = bytes((i + k) % 256 for k in range(width * height * 3))
                image = Image(header=header, height=height, width=width, encoding="rgb8",
                              step=width * 3, data=data)
                bag.write("/camera/rgb/image_raw", image, stamp + genpy.Duration(0, 3000))
                bag.write("/detections", detection, stamp + genpy.Duration(0, 4000),
                          connection_header=detection_header)


def bag_contents(path):
    connections, messages = set(), []
    for topic, raw, stamp, header in iter_bag(path):
        connections.add((topic, header["type"], header["md5sum"], header["message_definition"]))
        messages.append((topic, stamp.to_nsec(), raw))
    return connections, messages


def test_bag_to_database_to_bag_is_lossless(db_url, tmp_path):
    source, copy = tmp_path / "source.bag", tmp_path / "copy.bag"
    write_bag(source)
    with open_store(db_url) as store:
        result = import_bag(source, store, tags=["lab"], progress=False)
        assert result.messages == 30 + 10 + 10 + 3 + 3
        assert import_bag(source, store, progress=False).messages == 56  # again: nothing stored twice
        assert store.count() == 56
        assert store.count_messages(tags=["lab"], topic="/detections") == 3
        latched = [i for i in store.topics() if i.topic == "/detections"]
        assert latched[0].latching and latched[0].callerid == "/detector"
        exported = export_bag(store, parse_query(""), copy, progress=False)
    assert exported.messages == 56
    assert bag_contents(copy) == bag_contents(source)
    headers = {topic: header for topic, _, _, header in iter_bag(copy)}
    assert headers["/detections"]["latching"] == "1"


def test_export_of_a_query_refuses_to_overwrite(db_url, tmp_path):
    source, part = tmp_path / "source.bag", tmp_path / "scan.bag"
    write_bag(source)
    with open_store(db_url) as store:
        import_bag(source, store, progress=False)
        export_bag(store, parse_query("topic /scan"), part, progress=False)
        with pytest.raises(BagError, match="exists"):
            export_bag(store, parse_query("topic /scan"), part, progress=False)
    _, messages = bag_contents(part)
    assert [m[0] for m in messages] == ["/scan"] * 10


def run_cli(workspace_root, *args):
    script = workspace_root / "src" / "ros_mongo" / "scripts" / "ros_mongo_bag"
    return subprocess.run([sys.executable, str(script), "--no-progress", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_cli_round_trip_and_clear_errors(couchdb_url, tmp_path, workspace_root):
    source = tmp_path / "source.bag"
    write_bag(source)
    done = run_cli(workspace_root, "--db-url", couchdb_url, "import", source)
    assert done.returncode == 0, done.stderr
    assert "56 messages" in done.stdout
    info = run_cli(workspace_root, "info", "--db-url", couchdb_url)
    assert "/camera/rgb/image_raw" in info.stdout and "3 messages" in info.stdout
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    cases = [
        (("import", broken), "ERROR: cannot read bag"),
        (("import", tmp_path / "missing.bag"), "ERROR: cannot read bag"),
        (("export", source), "ERROR: bag .* exists"),
        (("export", tmp_path / "x.bag", "--query", "colour red"), "ERROR: unknown query key"),
    ]
    for args, message in cases:
        failed = run_cli(workspace_root, "--db-url", couchdb_url, *args)
        lines = failed.stderr.strip().splitlines()
        assert failed.returncode == 1 and len(lines) == 1, failed.stderr
        assert re.match(message, lines[0]), lines[0]


@pytest.mark.ros
def test_bag_converter_launch(roslaunch, couchdb_url, tmp_path):
    source = tmp_path / "source.bag"
    write_bag(source)
    launch = roslaunch("ros_mongo", "bag_converter.launch", direction="import", bag=str(source),
                       db_url=couchdb_url, tags="converted")
    assert launch.wait_for_exit(120) == 0, launch.log_tail()
    with open_store(couchdb_url) as store:
        wait_until(lambda: store.count_messages(tags=["converted"]) == 56, 90, what="imported messages")
