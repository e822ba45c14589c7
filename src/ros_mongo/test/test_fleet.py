"""Fleet replication as users run it: robots record locally and push to a central CouchDB database.

Real processes only: one pouchdb-server per robot plus a central one (ros_harness; once a real
Apache CouchDB central written as its member), real roscores
(one per robot, as on real robots) and the nodes through roslaunch (launch/fleet.launch). Counts
and ids are read from the stores, never built here.
"""
import re
import time
import uuid
from pathlib import Path
from urllib.parse import unquote

import pytest
import requests
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from fleet_helpers import FleetRobot, all_docs, content, holds, messages
from nav_msgs.msg import Odometry
from ros_mongo_samples import serialized
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from ros_harness import LaunchSet, PouchDBServer, RosCore, wait_for_subscriber, wait_until
from ros_mongo import TopicInfo, make_record, open_store
from ros_mongo.fleet.replication import (
    POUCHDB_BATCH_SIZE,
    CouchDatabase,
    PushReplication,
    ReplicationError,
    ReplicationSpec,
)
from ros_mongo.fleet.retention import Retention
from ros_mongo.records import split_time

FIRST = 3 * POUCHDB_BATCH_SIZE  # messages replicated before central stops

LONG = 300.0  # seconds: generous, the machine is busy


def count_messages(db_url):
    try:
        return len(messages(all_docs(db_url)))
    except (requests.RequestException, ValueError, KeyError):
        return -1


def robot_counts(db_url):
    try:
        found = {}
        for doc in messages(all_docs(db_url)):
            found[doc["robot_id"]] = found.get(doc["robot_id"], 0) + 1
        return found
    except (requests.RequestException, ValueError, KeyError):
        return {}


# -- the selector and retention (real servers, no ROS) ---------------------------------------

def test_selector_keeps_design_docs_tombstones_and_local_topics_home():
    spec = ReplicationSpec(local_topics=("/camera/rgb/image_raw",))
    assert spec.selector() == {"kind": {"$in": ["message", "chunk", "topic"]},
                               "topic": {"$nin": ["/camera/rgb/image_raw"]}}
    assert spec.selects({"_id": "m", "kind": "message", "topic": "/odom"})
    assert spec.selects({"_id": "c", "kind": "chunk", "topic": "/odom"})
    assert spec.selects({"_id": "t", "kind": "topic", "topic": "/odom"})
    assert not spec.selects({"_id": "_design/idx", "views": {}})
    assert not spec.selects({"_id": "m", "_deleted": True})
    assert not spec.selects({"_id": "i", "kind": "message", "topic": "/camera/rgb/image_raw"})
    only = ReplicationSpec(topics=("/odom",))
    assert not only.selects({"_id": "s", "kind": "message", "topic": "/scan"})
    with pytest.raises(ReplicationError, match="'odom'"):
        ReplicationSpec(topics=("odom",))
    with pytest.raises(ReplicationError, match="/odom"):
        ReplicationSpec(topics=("/odom",), local_topics=("/odom",))


def _put(db_url, doc):
    response = requests.put(f"{db_url}/{doc['_id']}", json=doc, timeout=30)
    assert response.status_code == 201, response.text
    return response.json()["rev"]


@pytest.mark.db
def test_retention_deletes_only_old_documents_central_holds(tmp_path):
    with PouchDBServer(tmp_path / "robot") as robot, PouchDBServer(tmp_path / "central") as central:
        local_url, central_url = robot.database_url("robot_data"), central.database_url("fleet")
        for url in (local_url, central_url):
            assert requests.put(url, timeout=30).status_code == 201
        now = 1_000_000.0
        old, new = now - 3600, now - 10
        docs = {
            "old-central": {"kind": "message", "topic": "/odom", "receive_time": old},
            "old-missing": {"kind": "message", "topic": "/odom", "receive_time": old},
            "old-other-rev": {"kind": "message", "topic": "/odom", "receive_time": old},
            "new-central": {"kind": "message", "topic": "/odom", "receive_time": new},
            "old-local-topic": {"kind": "message", "topic": "/camera", "receive_time": old},
            "old-undated": {"kind": "message", "topic": "/odom"},
            "topic-odom": {"kind": "topic", "topic": "/odom"},
        }
        revs = {doc_id: _put(local_url, dict(body, _id=doc_id)) for doc_id, body in docs.items()}
        # central holds these with the very same revision (new_edits=false keeps the revision)
        same = [dict(docs[i], _id=i, _rev=revs[i]) for i in
                ("old-central", "new-central", "old-local-topic", "old-undated", "topic-odom")]
        answer = requests.post(central_url + "/_bulk_docs", json={"docs": same, "new_edits": False},
                               timeout=30)
        assert answer.status_code == 201, answer.text
        _put(central_url, dict(docs["old-other-rev"], _id="old-other-rev", note="other"))

        retention = Retention(CouchDatabase(local_url), CouchDatabase(central_url),
                              ReplicationSpec(local_topics=("/camera",)), older_than=600,
                              page=2, clock=lambda: now)
        result = retention.run_once()
        assert result.deleted == 1
        remaining = {d["_id"] for d in all_docs(local_url)}
        assert remaining == set(docs) - {"old-central"}
        assert requests.get(local_url + "/old-central", timeout=30).status_code == 404
        assert result.kept_unconfirmed == 2  # old-missing, old-other-rev
        # central still has everything it had; nothing was deleted there
        assert {d["_id"] for d in all_docs(central_url)} == {
            "old-central", "new-central", "old-local-topic", "old-undated", "topic-odom",
            "old-other-rev"}
        with pytest.raises(ReplicationError, match="-5"):
            Retention(CouchDatabase(local_url), CouchDatabase(central_url), ReplicationSpec(),
                      older_than=-5)


# -- outages of one robot's link (real servers and replication, the recorder's store API) ------

def record_odometry(store, robot_id, first, count):
    """Record Odometry messages numbered first.. (frame_id) as the recorder does: the store API's
    batched insert_records (one request per batch, not one per message)."""
    store.put_topic(TopicInfo.of_class("/odom", Odometry))
    records = []
    for index in range(first, first + count):
        msg = Odometry()
        msg.header.frame_id = str(index)
        records.append(make_record("/odom", Odometry, serialized(msg), receive=split_time(time.time()),
                                   robot_id=robot_id, message=msg))
    assert store.insert_records(records) == count


def server_log_since_start(server):
    """pouchdb-server's request log (log.txt in its data directory) since its last start."""
    text = (server.data_dir / "log.txt").read_text(errors="replace")
    return text[text.rindex("pouchdb-server has started"):]


def same_documents(local_url, central_url):
    """The replicated documents of the robot, each central with the same revision."""
    central = {d["_id"]: d["_rev"] for d in all_docs(central_url)}
    local = {d["_id"]: d["_rev"] for d in all_docs(local_url) if d.get("kind") in ("message", "topic")}
    return local == {i: central.get(i) for i in local}


@pytest.mark.db
def test_central_restart_resumes_replication_from_its_checkpoint(tmp_path):
    robot_id = "robot_a"
    with PouchDBServer(tmp_path / "robot") as robot:
        central = PouchDBServer(tmp_path / "central").start()
        try:
            local_url, central_url = robot.database_url("robot_data"), central.database_url("fleet")
            assert requests.put(central_url, timeout=30).status_code == 201
            with open_store(local_url) as store:
                record_odometry(store, robot_id, 0, FIRST)
                local = CouchDatabase(local_url)
                replication = PushReplication.for_robot(local, CouchDatabase(central_url), robot_id)
                replication.start()
                wait_until(lambda: holds(central_url, FIRST) and count_messages(central_url) == FIRST, LONG,
                           what=f"{FIRST} messages central")
                # the checkpoint the store's replicator keeps on central (its id from central's log)
                log = server_log_since_start(central)
                checkpoint_ids = set(re.findall(r"PUT /fleet/_local/(\S+) 201", log))
                assert len(checkpoint_ids) == 1, log[-2000:]
                checkpoint_url = central_url + "/_local/" + checkpoint_ids.pop()

                def checkpoint_seq():
                    return requests.get(checkpoint_url, timeout=30).json()["last_seq"]

                wait_until(lambda: checkpoint_seq() >= FIRST, LONG, what=f"a checkpoint after {FIRST}")
                before = checkpoint_seq()
                first_run_diffs = log.count("POST /fleet/_revs_diff")
                # FIRST changes in batches of POUCHDB_BATCH_SIZE: a replay from zero is visible
                assert first_run_diffs >= 3

                central.stop()
                record_odometry(store, robot_id, FIRST, 60)  # recording goes on, central is down
                assert count_messages(local_url) == FIRST + 60
                central.start()
                replication.trigger()  # what the replicator node does when central is back
                wait_until(lambda: holds(central_url, FIRST + 60)
                           and count_messages(central_url) == FIRST + 60, LONG,
                           what="every message central")
                wait_until(lambda: checkpoint_seq() > before, LONG, what="the checkpoint moving on")

                log = server_log_since_start(central)
                # the restarted replication read its checkpoint and sent only what came after it:
                # a replay from zero compares all FIRST + 60 changes again (at least as many _revs_diff
                # requests as the first run)
                assert re.search(r"GET /fleet/_local/\S+ 200", log), log[-2000:]
                assert log.count("POST /fleet/_revs_diff") < first_run_diffs, log[-3000:]
                assert same_documents(local_url, central_url)
                stored = sorted(content(d)[2] for d in messages(all_docs(central_url)))
                assert stored == list(range(FIRST + 60))
                replication.stop()
        finally:
            central.stop()


@pytest.mark.db
def test_a_robot_pushes_to_a_real_couchdb_central_as_its_member(apache_couchdb, tmp_path):
    """pouchdb-server on the robot, a real Apache CouchDB central: the robot's replicator writes as
    a database member (created by the admin; no design document goes up); every message arrives
    with its revision and the image attachment intact."""
    robot_id, count = "robot_m", 300
    central_url = apache_couchdb.database_url("fleet_" + uuid.uuid4().hex[:8])
    admin_url = central_url.replace(":".join(apache_couchdb.member), ":".join(apache_couchdb.admin))
    with PouchDBServer(tmp_path / "robot") as robot:
        local_url = robot.database_url("robot_data")
        with open_store(local_url) as store:
            record_odometry(store, robot_id, 0, count)
            pixels = bytes(i % 251 for i in range(640 * 480))
            store.insert_message("/camera/rgb/image_raw", Image(height=480, width=640, encoding="mono8",
                                                                 step=640, data=pixels), robot_id=robot_id)
        replication = PushReplication.for_robot(CouchDatabase(local_url), CouchDatabase(central_url),
                                                robot_id)
        replication.start()
        wait_until(lambda: holds(admin_url, count + 1) and count_messages(admin_url) == count + 1, LONG,
                   what=f"{count + 1} messages central")
        wait_until(lambda: same_documents(local_url, admin_url), LONG, what="the same revisions central")
        docs = all_docs(admin_url)
        image = next(d for d in messages(docs) if d["topic"] == "/camera/rgb/image_raw")
        raw = requests.get(f"{admin_url}/{image['_id']}/raw", timeout=30)
        assert raw.status_code == 200 and raw.content.endswith(pixels)
        assert sorted(content(d)[2] for d in messages(docs) if d["topic"] == "/odom") == list(range(count))
        assert not any(d["_id"].startswith("_design/") for d in docs)
        replication.stop()


@pytest.mark.db
def test_robot_store_restart_mid_replication_loses_nothing(tmp_path):
    """The robot's store restarts while its replication is under way: 20 images are central,
    20 more wait to be sent. Central is stopped meanwhile, so "mid-replication" is a state the
    test sets, not a race with the replicator it hopes to win."""
    robot_id = "robot_b"
    pixels = bytes(i % 251 for i in range(640 * 480))

    def record_images(store, first, count):  # 307 KB each: attachments
        for index in range(first, first + count):
            image = Image(height=480, width=640, encoding="mono8", step=640, data=pixels)
            image.header.frame_id = str(index)
            store.insert_message("/camera/rgb/image_raw", image, robot_id=robot_id)

    central = PouchDBServer(tmp_path / "central").start()
    robot = PouchDBServer(tmp_path / "robot").start()
    try:
        local_url, central_url = robot.database_url("robot_data"), central.database_url("fleet")
        assert requests.put(central_url, timeout=30).status_code == 201
        with open_store(local_url) as store:
            record_images(store, 0, 20)
        local = CouchDatabase(local_url)
        replication = PushReplication.for_robot(local, CouchDatabase(central_url), robot_id)
        replication.start()
        wait_until(lambda: holds(central_url, 20) and count_messages(central_url) == 20, LONG,
                   what="the first 20 images central")
        central.stop()
        with open_store(local_url) as store:
            record_images(store, 20, 20)  # pending: the replicator cannot send them
        robot.restart()  # the store (and its replicator) stops mid-replication and comes back
        with open_store(local_url) as store:
            record_odometry(store, robot_id, 0, 30)  # recording after the restart
        central.start()
        # the replication document persisted: the restarted store's replicator resumes it; the
        # trigger is what the replicator node does when central answers again
        replication.trigger()
        wait_until(lambda: holds(central_url, 70) and count_messages(central_url) == 70, LONG,
                   what="70 messages central")
        assert same_documents(local_url, central_url)
        central_docs = all_docs(central_url)
        assert [d["_id"] for d in central_docs if d.get("_conflicts")] == []
        found = sorted((d["topic"], content(d)[2]) for d in messages(central_docs))
        assert found == sorted([("/camera/rgb/image_raw", i) for i in range(40)]
                               + [("/odom", i) for i in range(30)])
        image = next(d for d in messages(central_docs) if d["topic"] == "/camera/rgb/image_raw")
        raw = requests.get(f"{central_url}/{unquote(image['_id'])}/raw", timeout=30)
        assert raw.status_code == 200 and len(raw.content) == image["size"]
        replication.stop()
    finally:
        robot.stop()
        central.stop()


# -- one robot: diagnostics and services -------------------------------------------------------

class ReplicatorStatus:
    def __init__(self, robot_id):
        self.name = f"ros_mongo_replicator: {robot_id}"
        self.values, self.level = {}, None
        self.subscriber = rospy.Subscriber("/diagnostics", DiagnosticArray, self._receive)

    def _receive(self, msg):
        for status in msg.status:
            if status.name == self.name:
                self.values = {kv.key: kv.value for kv in status.values}
                self.level = status.level

    def get(self, key, default=""):
        return self.values.get(key, default)


@pytest.mark.ros
@pytest.mark.db
def test_replicator_reports_lag_and_obeys_start_stop_trigger(roslaunch, rospy_node, workspace_root,
                                                             tmp_path):
    robot_id = f"robot_{uuid.uuid4().hex[:6]}"
    with PouchDBServer(tmp_path / "robot") as robot, PouchDBServer(tmp_path / "central") as central:
        central_url = central.database_url("fleet")
        status = ReplicatorStatus(robot_id)
        launch = roslaunch(str(workspace_root / "launch" / "fleet.launch"), central_url=central_url,
                           robot_id=robot_id, local_db="true", local_db_server="false",
                           local_db_port=robot.port,
                           topics="[/odom]", spool_path=str(tmp_path / "spool"))
        launch.wait_for_services(["/ros_mongo_replicator/stop", "/ros_mongo_replicator/start",
                                  "/ros_mongo_replicator/trigger"], timeout=LONG)
        wait_until(lambda: status.get("state") == "running", LONG, what="replication running")
        publisher = rospy.Publisher("/odom", Odometry, queue_size=1000)
        wait_for_subscriber(publisher, "/ros_mongo_server", LONG)

        def send(first, count):
            for index in range(first, first + count):
                msg = Odometry()
                msg.header.frame_id = str(index)
                publisher.publish(msg)
                rospy.sleep(0.01)  # the publisher's pace, not synchronisation

        send(0, 20)
        wait_until(lambda: holds(central_url, 20) and count_messages(central_url) == 20, LONG,
                   what="20 messages central")
        wait_until(lambda: status.get("pending_docs") == "0", LONG, what="nothing pending")

        stop = rospy.ServiceProxy("/ros_mongo_replicator/stop", Trigger)()
        assert stop.success, stop.message
        wait_until(lambda: status.get("state") == "stopped", LONG, what="state stopped")
        send(20, 30)
        wait_until(lambda: holds(robot.database_url("robot_data"), 50)
                   and count_messages(robot.database_url("robot_data")) == 50, LONG,
                   what="50 messages in the robot's store")
        wait_until(lambda: int(status.get("lag_docs", "0")) >= 30, LONG, what="lag of 30 documents")
        assert float(status.get("lag_seconds")) > 0
        assert status.level == 1  # WARN: stopped by request
        assert count_messages(central_url) == 20  # nothing went up while stopped

        start = rospy.ServiceProxy("/ros_mongo_replicator/start", Trigger)()
        assert start.success, start.message
        wait_until(lambda: holds(central_url, 50) and count_messages(central_url) == 50, LONG,
                   what="50 messages central")
        wait_until(lambda: status.get("pending_docs") == "0", LONG, what="caught up")
        trigger = rospy.ServiceProxy("/ros_mongo_replicator/trigger", Trigger)()
        assert trigger.success, trigger.message
        assert status.get("central") == central_url
        assert status.get("last_error") == ""
        status.subscriber.unregister()
        publisher.unregister()


# -- robots with local stores, central and local outages ---------------------------------------------------

class Robot(FleetRobot):
    """One robot: its own roscore, local store and fleet.launch."""

    def __init__(self, index, work: Path, central_url, workspace_root):
        self.robot_id = f"robot{index}"
        self.work = work / self.robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.store = PouchDBServer(self.work / "store").start()
        self.url = self.store.database_url("robot_data")
        self.launches = LaunchSet(self.core, self.work / "launch")
        self.launch = self.launches(str(workspace_root / "launch" / "fleet.launch"),
                                    central_url=central_url, robot_id=self.robot_id,
                                    local_db="true", local_db_server="false",
                                    local_db_port=self.store.port,
                                    topics="[/odom, /camera/rgb/image_raw]",
                                    spool_path=str(self.work / "recorder.spool"))
        self.publisher = None

    def close(self):
        super().close()
        self.store.stop()


@pytest.mark.ros
@pytest.mark.db
def test_robots_with_local_stores_put_each_message_central_once_through_outages(tmp_path, workspace_root):
    """fleet.launch local_db:=true: two robots' stores replicate to central through a central outage
    and a robot store restart."""
    count, rate, hold = 200, 40.0, 60
    central = PouchDBServer(tmp_path / "central").start()
    robots = []
    try:
        robots = [Robot(i, tmp_path, central.database_url("fleet"), workspace_root) for i in (1, 2)]
        central_url = central.database_url("fleet")
        wait_until(lambda: requests.get(central_url, timeout=5).ok, LONG, what="central database")
        for robot in robots:
            robot.launch.wait_for_subscribers(["/odom", "/camera/rgb/image_raw"], timeout=LONG)
            robot.publish(count, rate, hold_at=hold)

        # mid-stream: every robot has replicated some messages, then the central server stops
        wait_until(lambda: holds(central_url, 30 * len(robots))
                   and all(robot_counts(central_url).get(r.robot_id, 0) >= 30 for r in robots),
                   LONG, what="30 messages of each robot central")
        central.stop()
        held = {r.robot_id: count_messages(r.url) for r in robots}
        for robot in robots:
            robot.go_file.touch()  # the rest of the stream comes while central is down
        wait_until(lambda: all(holds(r.url, held[r.robot_id] + 40)
                               and count_messages(r.url) >= held[r.robot_id] + 40 for r in robots),
                   LONG, what="recording goes on while central is down")
        # a robot's local store restarts mid-replication (the recorder spools meanwhile)
        robots[0].store.restart()
        central.start()

        wait_until(lambda: not any(r.publisher.alive for r in robots), LONG, what="all published")
        published = {r.robot_id: r.published() for r in robots}
        expected = sum(sum(p.values()) for p in published.values())
        wait_until(lambda: holds(central_url, expected) and count_messages(central_url) == expected, LONG,
                   what=f"{expected} messages central")

        central_docs = all_docs(central_url)
        assert [d["_id"] for d in central_docs if d.get("_conflicts")] == []
        central_revs = {d["_id"]: d["_rev"] for d in central_docs}
        local_total = 0
        for robot in robots:
            local = all_docs(robot.url)
            local_messages = messages(local)
            local_total += len(local_messages)
            # the robot recorded every message it was sent (local store restart included)
            seqs = sorted(content(d)[1:] for d in local_messages)
            sent = published[robot.robot_id]
            assert sent == {"/odom": count, "/camera/rgb/image_raw": count // 10}
            assert seqs == sorted([("/odom", i) for i in range(count)]
                                  + [("/camera/rgb/image_raw", i) for i in range(0, count, 10)])
            # central holds each of the robot's documents with the same revision
            for doc in local:
                if doc.get("kind") in ("message", "topic"):
                    assert central_revs.get(doc["_id"]) == doc["_rev"], doc["_id"]
        # each message exactly once, by content
        contents = [content(d) for d in messages(central_docs)]
        assert len(contents) == len(set(contents)) == expected == local_total
        assert {c[0] for c in contents} == {r.robot_id for r in robots}
        # images arrived with their bytes (attachments)
        image = next(d for d in messages(central_docs) if d["topic"] == "/camera/rgb/image_raw")
        raw = requests.get(f"{central_url}/{image['_id']}/raw", timeout=30)
        assert raw.status_code == 200 and len(raw.content) == image["size"]
    finally:
        for robot in robots:
            robot.close()
        central.stop()
