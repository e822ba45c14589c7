"""The original mongodb_api README's commands, with `ros_mongo` in place of `mongodb_api`, against
a MongoDB (nx-27017) holding data in the original layout: flat documents in test_database.posts,
written here with pymongo as the original's server wrote them. Real roscore, roslaunch and
database; the expected values are written by hand from the seeded documents."""
import json
import subprocess
import sys
import time

import pymongo
import pytest
import rosbag
import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan

from ros_harness import free_port, wait_until
from ros_mongo import open_store
from ros_mongo.query import Query
from ros_mongo.srv import SensorData

pytestmark = [pytest.mark.ros, pytest.mark.db]

T0 = 1545000000.0


def _lidar(i, author, ranges):
    return {"session_id": 1, "author": author, "time": T0 + i, "tags": ["lidar"], "time_increment": 0.5,
            "angle_min": 0.0, "angle_max": 100.0, "range_min": 10.0, "range_max": 20.0,
            "angle_increment": 20.0, "ranges": ranges}


def _odom(i, author, x):
    return {"session_id": 1, "author": author, "time": T0 + i, "tags": ["odom"],
            "position": [x, 2.0, 0.0], "velocity": [0.5, 0.0, 0.1]}


#: the original layout, in time order: ServiceRobot's lidar 1, 2, 3 and odom 7, 8; OtherRobot's
#: lidar 4, 5 between them; one joint_states, one image, one document of a sensor never logged
ORIGINAL_POSTS = [
    _lidar(0, "ServiceRobot", [1.0, 1.0]),
    _odom(1, "ServiceRobot", 7.0),
    _lidar(2, "OtherRobot", [4.0]),
    _lidar(3, "ServiceRobot", [2.0, 2.0]),
    {"session_id": 1, "author": "OtherRobot", "time": T0 + 4, "tags": ["joint_states"],
     "joint_names": ["wheel_left", "wheel_right"], "position": [0.1, 0.2], "velocity": [0.0, 0.0],
     "effort": [0.0, 0.0]},
    _lidar(5, "OtherRobot", [5.0]),
    {"session_id": 1, "author": "OtherRobot", "time": T0 + 6, "tags": ["image"], "height": 2, "width": 2,
     "data": bytes([0, 64, 128, 255])},
    _odom(7, "ServiceRobot", 8.0),
    _lidar(8, "ServiceRobot", [3.0, 3.0]),
    {"session_id": 1, "author": "ServiceRobot", "time": T0 + 9, "tags": ["kinect"], "depth": [1, 2]},
]


@pytest.fixture
def original_database(mongodb_server):
    """test_database.posts seeded in the original layout (the database is the original's, so it
    is emptied first)."""
    client = pymongo.MongoClient(mongodb_server.url)
    client.drop_database("test_database")
    client["test_database"]["posts"].insert_many([dict(doc) for doc in ORIGINAL_POSTS])
    yield client["test_database"]
    client.drop_database("test_database")
    client.close()


@pytest.fixture
def original_config(mongodb_server, tmp_path):
    """The original's config/server_config.yaml, pointing at the test's MongoDB."""
    path = tmp_path / "server_config.yaml"
    path.write_text(f"server_ip : '127.0.0.1'\nport : {mongodb_server.port}\ndata_rate : 50\n"
                    "log_image : true\nlog_joint : true\nlog_lidar : true\nlog_odom : true\n"
                    "log_realsense : true\nlog_kinect : true\nauthor : 'ServiceRobot'\nsession_id : 1\n"
                    "bag_name : 'mongodb_to_bag.bag'\nwhere_to_write : 'write_bag'\n")
    return path


def _bag_tool(workspace_root, *args):
    script = workspace_root / "src" / "ros_mongo" / "scripts" / "ros_mongo_bag"
    return subprocess.run([sys.executable, str(script), "--no-progress", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


class Collector:
    """Every message received on `topics`, as (topic, bytes), in arrival order."""

    def __init__(self, topics):
        self.got = []
        self.subscribers = [rospy.Subscriber(t, rospy.AnyMsg, self._receive, callback_args=t) for t in topics]

    def _receive(self, msg, topic):
        self.got.append((topic, msg._buff))

    def close(self):
        for subscriber in self.subscribers:
            subscriber.unregister()


def test_migrate_reads_the_original_layout_reports_per_field_and_is_idempotent(
        workspace_root, mongodb_server, original_database):
    target = f"{mongodb_server.url}/test_database"
    done = _bag_tool(workspace_root, "migrate", "--from-url", mongodb_server.url, "--db-url", target)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "read 10 original documents: 9 messages stored, 0 already present (not rewritten), " \
           "1 skipped" in out
    assert "skipped 1: unknown tag 'kinect'" in out
    assert "lidar (/scan, sensor_msgs/LaserScan): 5 documents" in out
    assert "reconstructed ranges: 5" in out and "missing intensities: 5" in out
    assert "missing pose.pose.orientation: 2" in out and "missing encoding: 1" in out
    assert "never stored by the original, not invented: exact serialized bytes" in out

    again = _bag_tool(workspace_root, "migrate", "--from-url", mongodb_server.url, "--db-url", target)
    assert again.returncode == 0, again.stderr
    assert "0 messages stored, 9 already present (not rewritten), 1 skipped" in again.stdout
    assert original_database["posts"].count_documents({}) == 10  # the original data is untouched

    with open_store(target) as store:
        assert store.count(Query()) == 9
        scans = list(store.find(Query(author="ServiceRobot", tags=["lidar"])))
        assert [list(m.message().ranges) for m in scans] == [[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]
        assert {(m.topic, m.session_id, m.receive_time) for m in scans} == \
            {("/scan", "1", T0), ("/scan", "1", T0 + 3), ("/scan", "1", T0 + 8)}
        odom = [m.message() for m in store.find(Query(topics=["/odom"]))]
        assert [(o.pose.pose.position.x, o.twist.twist.linear.x, o.twist.twist.angular.z) for o in odom] == \
            [(7.0, 0.5, 0.1), (8.0, 0.5, 0.1)]
        image = next(iter(store.find(Query(tags=["image"])))).message()
        assert (image.height, image.width, bytes(image.data)) == (2, 2, bytes([0, 64, 128, 255]))


def test_the_original_readme_commands(roslaunch, rospy_node, workspace_root, mongodb_server,
                                      original_database, original_config, tmp_path):
    target = f"{mongodb_server.url}/test_database"
    assert _bag_tool(workspace_root, "migrate", "--from-url", mongodb_server.url, "--db-url",
                     target).returncode == 0

    # roslaunch ros_mongo launch_server.launch (the original's server_config.yaml as global parameters)
    server = roslaunch("ros_mongo", "launch_server.launch", config=original_config,
                       spool_path=tmp_path / "spool")
    server.wait_for_nodes(["/ros_mongo_server"], timeout=90)
    # roslaunch ros_mongo test_launch.launch: sample LaserScans on /scan at data_rate
    publisher = roslaunch("ros_mongo", "test_launch.launch", config=original_config, count=20)
    with open_store(target) as store:
        recorded = Query(author="ServiceRobot", session_id="1", tags=["lidar"], start_time=T0 + 100)
        wait_until(lambda: store.count(recorded) == 20, 120, what="20 sample scans recorded")
    assert publisher.wait_for_exit(90) == 0
    log = server.log_tail(400)
    assert "deprecated global parameter 'server_ip' (mongodb_api): use ~db_url instead" in log
    assert "deprecated global parameter 'author' (mongodb_api): use ~author instead" in log
    roslaunch.stop(server)

    # roslaunch ros_mongo retrieve.launch query:='author ServiceRobot'
    collector = Collector(["/scan_mongo", "/odom_mongo"])
    retriever = roslaunch("ros_mongo", "retrieve.launch", query="author ServiceRobot", config=original_config,
                          start_delay=10)  # waits (at most 10 s) for the collector to connect
    expected = 3 + 2 + 20  # ServiceRobot's migrated lidar and odom, then the recorded samples
    try:
        wait_until(lambda: len(collector.got) >= expected, 120, what=f"{expected} messages replayed")
    except TimeoutError as err:
        raise AssertionError(f"{err}; got {len(collector.got)}\n{retriever.log_tail()}") from None
    # per topic in recorded order (two topics' subscriber connections may deliver out of step on a
    # busy machine, so the order across topics is not compared); OtherRobot's left out
    scan_bytes = [raw for topic, raw in collector.got if topic == "/scan_mongo"]
    odoms = [Odometry().deserialize(raw).pose.pose.position.x for topic, raw in collector.got
             if topic == "/odom_mongo"]
    assert [list(LaserScan().deserialize(raw).ranges) for raw in scan_bytes[:3]] == \
        [[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]
    assert odoms == [7.0, 8.0]
    samples = [LaserScan().deserialize(raw) for raw in scan_bytes[3:]]
    assert len(samples) == 20
    assert all(list(s.ranges) == [10.0, 10.0, 20.0, 20.0, 10.0] and s.angle_max == 100.0 for s in samples)
    # SensorData.srv: the same messages in the original's flat form
    retriever.wait_for_services(["/ros_mongo_retriever/sensor_data"], timeout=90)
    answer = rospy.ServiceProxy("/ros_mongo_retriever/sensor_data", SensorData)("tags:lidar", 4)
    assert answer.success and answer.count == 25
    docs = [json.loads(d) for d in answer.documents]
    assert [(d["author"], d["time"], d["ranges"]) for d in docs] == [
        ("ServiceRobot", T0, [1.0, 1.0]), ("OtherRobot", T0 + 2, [4.0]), ("ServiceRobot", T0 + 3, [2.0, 2.0]),
        ("OtherRobot", T0 + 5, [5.0])]
    collector.close()
    roslaunch.stop(retriever)

    # a forgotten query: refused, as the original did
    refused = roslaunch("ros_mongo", "retrieve.launch", config=original_config)
    refused.wait_for_exit(120)
    assert "no query given: retrieve.launch needs one" in refused.log_tail(200)

    # roslaunch ros_mongo bag_converter.launch query:='tags lidar' (the original's defaults: export
    # to bag_name in the bag directory)
    bag_dir = tmp_path / "bag"
    converter = roslaunch("ros_mongo", "bag_converter.launch", query="tags lidar", config=original_config,
                          bag_dir=bag_dir)
    converter.wait_for_exit(180)
    bag_path = bag_dir / "mongodb_to_bag.bag"
    assert bag_path.exists(), converter.log_tail(200)
    with rosbag.Bag(str(bag_path)) as bag:
        written = [(topic, list(msg.ranges), t.to_sec()) for topic, msg, t in bag.read_messages()]
    assert len(written) == 5 + 20 and {topic for topic, _, _ in written} == {"/scan"}
    assert [(ranges, t) for _, ranges, t in written[:5]] == [
        ([1.0, 1.0], T0), ([4.0], T0 + 2), ([2.0, 2.0], T0 + 3), ([5.0], T0 + 5), ([3.0, 3.0], T0 + 8)]
    assert all(ranges == [10.0, 10.0, 20.0, 20.0, 10.0] and t > time.time() - 3600
               for _, ranges, t in written[5:])


def test_the_bag_converter_without_bag_exports_with_the_originals_defaults(workspace_root, couchdb_url,
                                                                          tmp_path):
    sent = LaserScan(ranges=[1.5, 2.5])
    with open_store(couchdb_url) as store:
        store.insert_message("/scan", sent, tags=["lidar"], receive_time=T0)
        store.insert_message("/odom", Odometry(), tags=["odom"], receive_time=T0 + 1)
    env_url = ["--db-url", couchdb_url]
    refused = _bag_tool(workspace_root, *env_url, "convert", "--bag-dir", tmp_path)
    assert refused.returncode == 1 and "no query given" in refused.stderr
    done = _bag_tool(workspace_root, *env_url, "convert", "--query", "tags:lidar", "--bag-dir", tmp_path)
    assert done.returncode == 0, done.stderr
    with rosbag.Bag(str(tmp_path / "mongodb_to_bag.bag")) as bag:
        written = [(topic, list(msg.ranges), t.to_sec()) for topic, msg, t in bag.read_messages()]
    assert written == [("/scan", [1.5, 2.5], T0)]


@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # its source is unreachable
def test_migrate_from_an_unreachable_server_fails_with_one_line(workspace_root, couchdb_url):
    done = _bag_tool(workspace_root, "migrate", "--from-url", f"mongodb://127.0.0.1:{free_port()}",
                     "--db-url", couchdb_url)
    assert done.returncode == 1
    errors = [line for line in done.stderr.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and "cannot read" in errors[0] and "test_database.posts" in errors[0]
