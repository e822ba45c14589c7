"""Bag -> database -> bag, byte for byte, on both backends; the command-line tool and its errors."""
import os
import re
import signal
import subprocess
import sys
import uuid

import genpy
import pytest
import rosbag
from nav_msgs.msg import Odometry
from ros_mongo_samples import custom_message
from sensor_msgs.msg import Image, JointState, LaserScan
from std_msgs.msg import Header

from ros_harness import wait_for_subscriber, wait_until
from ros_mongo import BagError, cli, open_store, parse_query
from ros_mongo.cli import parse_args, run
from ros_mongo.files.bagio import export_bag, import_bag, iter_bag

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


def test_cli_round_trip_and_clear_errors(couchdb_url, tmp_path, workspace_root, capsys, monkeypatch):
    source = tmp_path / "source.bag"
    write_bag(source)
    done = run_cli(workspace_root, "--db-url", couchdb_url, "import", source)  # the installed script
    assert done.returncode == 0, done.stderr
    assert "56 messages" in done.stdout
    # the other commands through the same entry point, in this process (quicker than a process each)
    monkeypatch.setattr(cli, "keep_freed_memory", lambda: True)  # no allocator tuning in pytest
    assert cli.main(["--no-progress", "info", "--db-url", couchdb_url]) == 0
    info = capsys.readouterr().out
    assert "/camera/rgb/image_raw" in info and "3 messages" in info
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    cases = [
        (("import", broken), "ERROR: cannot read bag"),
        (("import", tmp_path / "missing.bag"), "ERROR: cannot read bag"),
        (("export", source), "ERROR: bag .* exists"),
        (("export", tmp_path / "x.bag", "--query", "colour red"), "ERROR: unknown query key"),
        (("export", tmp_path / "x.bag", "--compression", "zstd"), "ERROR: bag compression must be one of"),
    ]
    for args, message in cases:
        status = cli.main(["--no-progress", "--db-url", couchdb_url, *map(str, args)])
        lines = capsys.readouterr().err.strip().splitlines()
        assert status == 1 and len(lines) == 1, lines
        assert re.match(message, lines[0]), lines[0]
    assert not (tmp_path / "x.bag").exists() and not (tmp_path / "x.bag.partial").exists()


@pytest.mark.ros
@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # the CLI's store path on both: above
def test_bag_converter_launch(roslaunch, couchdb_url, tmp_path):
    source = tmp_path / "source.bag"
    write_bag(source)
    launch = roslaunch("ros_mongo", "bag_converter.launch", direction="import", bag=str(source),
                       db_url=couchdb_url, tags="converted")
    assert launch.wait_for_exit(120) == 0, launch.log_tail()
    with open_store(couchdb_url) as store:
        wait_until(lambda: store.count_messages(tags=["converted"]) == 56, 90, what="imported messages")


def write_chunked_bag(path):
    """Two topics over many small chunks (as `rosbag record --chunksize` makes them)."""
    with rosbag.Bag(str(path), "w", chunk_threshold=2048) as bag:
        for i in range(60):
            stamp = genpy.Time(1_700_000_000 + i, 0)
            bag.write("/odom", Odometry(header=Header(seq=i, stamp=stamp, frame_id="odom")), stamp)
            if i % 4 == 0:
                bag.write("/joint_states", JointState(name=["a"] * 10, position=[0.1 * i] * 10),
                          stamp + genpy.Duration(0, 5))


def rosbag_reindexed(path, tmp_path):
    """What `rosbag reindex` (the real tool, on a copy) makes of an unindexed bag."""
    copy = tmp_path / "reindexed" / path.name
    copy.parent.mkdir()
    copy.write_bytes(path.read_bytes())
    done = subprocess.run(["rosbag", "reindex", "-q", str(copy)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return copy


def test_an_unindexed_bag_imports_what_rosbag_reindex_recovers(db_url, tmp_path):
    intact, cut = tmp_path / "intact.bag", tmp_path / "cut.bag"
    write_chunked_bag(intact)
    with rosbag.Bag(str(intact)) as bag:
        chunks = sorted(bag._chunks, key=lambda c: c.pos)
    assert len(chunks) > 10
    data = intact.read_bytes()[:chunks[8].pos + 30]  # cut inside the ninth chunk: no index at all
    cut.write_bytes(data)
    with pytest.raises(rosbag.ROSBagUnindexedException):
        rosbag.Bag(str(cut))
    reindexed = rosbag_reindexed(cut, tmp_path)
    _, expected = bag_contents(reindexed)
    # rosbag recovers whole chunks: the first `kept` ones (7 or 8 of the 8 complete ones)
    totals = [sum(sum(c.connection_counts.values()) for c in chunks[:k]) for k in range(10)]
    kept = totals.index(len(expected))
    assert kept in (7, 8)
    with open_store(db_url) as store:
        result = import_bag(cut, store, progress=False)
        assert result.messages == len(expected) and store.count() == len(expected)
        assert result.recovery.messages == len(expected) and result.recovery.topics == 2
        assert result.recovery.skipped_bytes == len(data) - chunks[kept].pos
        # the same ids as the bag rosbag reindex writes: importing that one stores nothing new
        assert import_bag(reindexed, store, progress=False).recovery is None
        assert store.count() == len(expected)
        out = tmp_path / "out.bag"
        export_bag(store, parse_query(""), out, progress=False)
    assert bag_contents(out)[1] == expected
    assert cut.read_bytes() == data  # the file itself is never modified (rosbag reindex truncates)


@pytest.mark.ros
@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # bag recovery, not the server
def test_a_bag_left_by_a_killed_rosbag_record_is_recovered(rospy_node, couchdb_url, mongodb_url, tmp_path,
                                                           capsys):
    """A real `rosbag record` of a real roscore, killed with SIGKILL while recording: its
    .bag.active file imports (CLI into CouchDB, API into MongoDB) as `rosbag reindex` recovers it."""
    from std_msgs.msg import String

    topic, size = f"/recorded_{uuid.uuid4().hex[:8]}", 3000
    recorder = f"/crash_record_{uuid.uuid4().hex[:8]}"        # the node name rosbag record runs under
    active = tmp_path / "crash.bag.active"
    publisher = rospy_node.Publisher(topic, String, queue_size=100)
    record = subprocess.Popen(["rosbag", "record", "--chunksize=1", "-O", str(tmp_path / "crash.bag"), topic,
                               f"__name:={recorder[1:]}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_for_subscriber(publisher, recorder, 90)
        sent = [f"message {i:03d} " + "x" * size for i in range(40)]
        for text in sent:
            publisher.publish(String(data=text))
        wait_until(lambda: active.exists() and active.stat().st_size > 30 * size, 90,
                   what="30 messages on disk")
    finally:
        os.killpg(record.pid, signal.SIGKILL)  # its own process group: the rosbag script and its recorder
        record.wait()
        publisher.unregister()
    _, expected = bag_contents(rosbag_reindexed(active, tmp_path))
    texts = [String().deserialize(raw).data for _, _, raw in expected]
    assert len(texts) >= 25 and texts == sent[:len(texts)]
    run(parse_args(["--no-progress", "--db-url", couchdb_url, "import", str(active)]))  # the command
    done = capsys.readouterr()
    assert f"{len(texts)} messages" in done.out, done.err
    assert re.search(rf"WARNING: .*crash.bag.active: unindexed bag: recovered {len(texts)} messages on 1 "
                     rf"topics, skipped \d+ unreadable bytes", done.err), done.err
    for url in (couchdb_url, mongodb_url):
        with open_store(url) as store:
            if url == mongodb_url:
                assert import_bag(active, store, progress=False).messages == len(texts)
            assert [m.raw for m in store.find_messages(topic=topic)] == [raw for _, _, raw in expected]
