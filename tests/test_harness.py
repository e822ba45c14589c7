"""The workspace and its test harness: generated messages, a real roscore, roslaunch with waits,
and real database servers (pouchdb-server for CouchDB, nx-27017 for MongoDB)."""
import json
import math
import signal
import sys
import urllib.request
import uuid
from io import BytesIO

import pytest

from ros_harness import (
    HarnessError,
    LaunchSet,
    ManagedProcess,
    ProcessDied,
    RosLaunch,
    http_get_json,
    master_graph,
    wait_until,
)


def test_generated_message_class_imports_and_round_trips():
    from robot_common.msg import ObjectObservation

    assert ObjectObservation._type == "robot_common/ObjectObservation"
    assert ObjectObservation.__slots__ == ["header", "class_name", "position", "confidence",
                                           "size", "region_id"]
    sent = ObjectObservation(class_name="chair", confidence=0.75, region_id="floor_4")
    sent.position.x, sent.size.z = 1.5, 0.9
    buffer = BytesIO()
    sent.serialize(buffer)
    received = ObjectObservation().deserialize(buffer.getvalue())
    assert (received.class_name, received.position.x, received.size.z, received.region_id) == \
        ("chair", 1.5, pytest.approx(0.9), "floor_4")


@pytest.mark.ros
def test_roscore_runs_on_a_free_port_with_rosout(roscore):
    graph = master_graph(roscore.uri)
    assert graph.lookupNode("/rosout")
    assert roscore.uri.startswith("http://127.0.0.1:") and not roscore.uri.endswith(":11311")


@pytest.mark.ros
def test_simulated_robot_launches_and_publishes_the_original_four_topics(roslaunch, rospy_node):
    from nav_msgs.msg import OccupancyGrid
    from sensor_msgs.msg import LaserScan

    sim = roslaunch("robot_sim", "sim.launch", seed=1)
    topics = ["/odom", "/scan", "/camera/rgb/image_raw", "/joint_states", "/map"]
    sim.wait_for_topics(topics, timeout=60)
    scan = rospy_node.wait_for_message("/scan", LaserScan, timeout=90)
    grid = rospy_node.wait_for_message("/map", OccupancyGrid, timeout=90)
    assert len(scan.ranges) == 360
    assert all(scan.range_min <= r <= scan.range_max for r in scan.ranges)
    assert min(scan.ranges) < 3.0  # inside a 3 m wide hall something is always near
    assert grid.info.width * grid.info.height == len(grid.data)
    assert sim.node_pid("/sensor_sim") > 0


@pytest.mark.ros
def test_single_node_with_private_params(roslaunch, rospy_node):
    from sensor_msgs.msg import Image

    node = roslaunch.node("robot_sim", "sensor_sim", name="camera_only",
                          params={"odom_rate": 0.0, "scan_rate": 0.0, "joint_rate": 0.0,
                                  "image_rate": 10.0, "image_width": 64, "image_height": 48},
                          remap={"camera/rgb/image_raw": "/cam"})
    node.wait_for_topics(["/cam"])
    image = rospy_node.wait_for_message("/cam", Image, timeout=90)
    assert (image.width, image.height, image.encoding, image.step) == (64, 48, "rgb8", 192)
    assert len(image.data) == 64 * 48 * 3


@pytest.mark.ros
def test_waiting_on_a_node_that_dies_reports_its_log(roscore, tmp_path):
    broken = RosLaunch.node("robot_sim", "map_publisher", name="broken_map_publisher",
                            master_uri=roscore.uri, log_dir=tmp_path, env=roscore.env(),
                            params={"map_yaml": str(tmp_path / "missing.yaml")})
    broken.start()
    try:
        # The node exits with its error; roslaunch, left with no process, exits too.
        with pytest.raises(ProcessDied, match="cannot read map file"):
            broken.wait_for_topics(["/map"], timeout=90)
    finally:
        broken.stop()


@pytest.mark.ros
def test_a_launch_set_stops_its_launches_and_deletes_their_parameters(roscore, tmp_path):
    launches = LaunchSet(roscore, tmp_path)
    node = launches.node("robot_sim", "map_publisher", name="set_map_publisher", params={"seed": 3})
    node.wait_for_topics(["/map"], timeout=60)
    graph = master_graph(roscore.uri)
    assert graph.getParam("/set_map_publisher/seed") == 3
    launches.stop_all()
    assert not node.process.alive and launches.launched == []
    assert not graph.hasParam("/set_map_publisher/seed")


@pytest.mark.ros
def test_a_launch_set_forgets_the_registrations_of_a_node_killed_without_unregistering(
        roscore, tmp_path):
    from ros_harness.launching import refuses_connections

    launches = LaunchSet(roscore, tmp_path)
    node = launches.node("robot_sim", "map_publisher", name="killed_map_publisher")
    node.wait_for_topics(["/map"], timeout=60)
    graph = master_graph(roscore.uri)

    def registered():
        publishers, _, services = graph.getSystemState()
        return ({topic for topic, nodes in publishers if "/killed_map_publisher" in nodes}
                | {name for name, nodes in services if "/killed_map_publisher" in nodes})

    uri = graph.lookupNode("/killed_map_publisher")
    node.process.kill()     # SIGKILL: the node cannot unregister
    # roslaunch runs its nodes in sessions of their own: the node is killed too, not orphaned
    wait_until(lambda: refuses_connections(uri), 30, what="the killed node's API to close")
    assert "/map" in registered()
    launches.stop_all()
    assert registered() == set()
    # the master itself and its rosout stay registered
    assert "/rosout" in {name for name, _ in graph.getSystemState()[0]}


def test_a_missing_program_is_a_clear_error(tmp_path, monkeypatch):
    from ros_harness import PouchDBServer

    monkeypatch.setenv("POUCHDB_SERVER_BIN", str(tmp_path / "nothing"))
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(HarnessError, match="pouchdb-server not found"):
        PouchDBServer(tmp_path).start()


def _request(method, url, body=None):
    data = json.dumps(body).encode() if body is not None else None
    request = urllib.request.Request(url, data=data, method=method,
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read().decode())


@pytest.mark.db
def test_couchdb_server_stores_documents_across_a_restart(own_couchdb_server):
    db = own_couchdb_server.database_url("harness_" + uuid.uuid4().hex[:8])
    assert _request("PUT", db)["ok"]
    doc_id = _request("POST", db, {"topic": "/odom", "x": math.pi})["id"]
    own_couchdb_server.restart()
    assert http_get_json(f"{db}/{doc_id}")["x"] == math.pi


@pytest.mark.db
def test_mongodb_server_round_trip(mongodb_url):
    import pymongo

    client = pymongo.MongoClient(mongodb_url, serverSelectionTimeoutMS=5000)
    collection = client.get_default_database()["messages"]
    collection.insert_many([{"topic": "/scan", "seq": i} for i in range(5)])
    found = list(collection.find({"seq": {"$gte": 3}}).sort("seq", pymongo.DESCENDING))
    assert [doc["seq"] for doc in found] == [4, 3]
    client.close()


@pytest.mark.db
def test_mongodb_server_keeps_data_across_a_restart(own_mongodb_server):
    import pymongo

    url = own_mongodb_server.database_url("restart")
    with pymongo.MongoClient(url, serverSelectionTimeoutMS=5000) as client:
        client.get_default_database()["m"].insert_one({"kept": True})
    own_mongodb_server.restart()
    with pymongo.MongoClient(url, serverSelectionTimeoutMS=5000) as client:
        assert client.get_default_database()["m"].count_documents({"kept": True}) == 1


@pytest.mark.db
def test_a_stopped_server_is_reported_dead(own_db_server):
    own_db_server.stop()
    with pytest.raises(ProcessDied):
        own_db_server.process.check_alive()


def test_the_real_couchdb_is_skipped_with_its_reason_where_the_shared_folder_is_absent(tmp_path):
    from ros_harness import ApacheCouchDB, HarnessError
    from ros_harness.apache_couchdb import missing_reason, shared_couchdb_dir

    assert shared_couchdb_dir(tmp_path / "clone") == tmp_path / "shared" / "couchdb"
    reason = missing_reason(tmp_path / "shared" / "couchdb")
    assert "couchdb-node.sh is missing" in reason and "../shared/couchdb" in reason
    with pytest.raises(HarnessError, match="is missing"):
        ApacheCouchDB(tmp_path / "shared" / "couchdb", tmp_path / "work").start()


def test_a_process_stops_on_sigint_even_when_the_suite_started_with_sigint_ignored(tmp_path):
    # A background job of a non-interactive shell (`make test &` in a script) ignores SIGINT, and
    # children inherit that: stop() would wait its whole timeout and then SIGKILL.
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        child = ManagedProcess([sys.executable, "-c", "import time; print('up', flush=True); "
                                "time.sleep(600)"], name="sleeper", log_path=tmp_path / "s.log")
        child.start()
        wait_until(lambda: "up" in child.log_tail(), 120, what="the child started")
        status = child.stop(timeout=120)
    finally:
        signal.signal(signal.SIGINT, before)
    assert status != -signal.SIGKILL, child.log_tail()
    assert "KeyboardInterrupt" in child.log_tail()
