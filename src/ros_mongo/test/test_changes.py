"""ros_mongo.fleet.changes: following a database's `_changes` feed (real pouchdb-server and Apache
CouchDB, no ROS)."""
import queue
import threading

import pytest
import requests
from nav_msgs.msg import Odometry
from std_msgs.msg import String

from ros_harness import ApacheCouchDB, PouchDBServer, wait_until
from ros_mongo import open_store
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.fleet.replication import ReplicationError, ReplicationUnavailable

LONG = 120.0


def record(store, robot_id, first, count):
    """Odometry (frame_id = index) and one String per 5 messages, as the recorder stores them."""
    for index in range(first, first + count):
        odom = Odometry()
        odom.header.frame_id = str(index)
        store.insert_message("/odom", odom, robot_id=robot_id)
        if index % 5 == 0:
            store.insert_message("/chatter", String(data=str(index)), robot_id=robot_id)


def test_selector_rules_are_apache_couchdbs():
    """The follower's selector means what it means to Apache CouchDB (ros_mongo.storage.mango, checked
    against the real server in test_mango.py): a present null is a value, a missing field fails
    everything but `$exists: false`."""
    follower = ChangesFollower("http://127.0.0.1:1/db", selector={"robot_id": None})
    doc = {"_id": "1", "kind": "message", "type": "nav_msgs/Odometry", "topic": "/odom", "robot_id": None}
    assert follower.selects(doc)                                      # $eq null: the present null
    assert not follower.selects(dict(doc, kind="topic"))              # kind "message" always
    assert not follower.selects({k: v for k, v in doc.items() if k != "robot_id"})  # missing
    assert not follower.selects(dict(doc, _deleted=True))
    regex = ChangesFollower("http://127.0.0.1:1/db", selector={"topic": {"$regex": "^/od"},
                                                                  "session_id": {"$in": [None]}})
    assert not regex.selects(doc) and regex.selects(dict(doc, session_id=None))
    with pytest.raises(ReplicationError, match=r"\$where"):
        ChangesFollower("http://127.0.0.1:1/db", selector={"topic": {"$where": "o"}})


def in_feed_order(frames, server):
    """`frames` as the feed promises them: in write order from pouchdb-server (one sequence);
    Apache CouchDB interleaves the feeds of a database's shards (q = 2 by default), so there each
    once, in any order (sorted here)."""
    return frames if isinstance(server, PouchDBServer) else sorted(frames, key=int)


@pytest.fixture(params=["pouchdb", "apache"])
def central(request, tmp_path):
    """A central server of this test's own (it is stopped and started): pouchdb-server, then a
    real Apache CouchDB node (the follower reads as a database member)."""
    if request.param == "apache":
        server = ApacheCouchDB(request.getfixturevalue("shared_couchdb"), tmp_path / "central")
    else:
        server = PouchDBServer(tmp_path / "central")
    yield server.start()
    server.stop()


@pytest.mark.db
def test_follows_selected_messages_resumes_from_a_sequence_and_survives_an_outage(central):
    server = central
    try:
        url = server.database_url("fleet")
        with open_store(url) as store:
            record(store, "robot1", 0, 20)
        follower = ChangesFollower(url, selector={"topic": "/odom"}, page=7)
        got, polls = [], 0
        while not follower.caught_up:
            got += follower.poll()
            polls += 1
        assert polls >= 4  # 20 + 4 messages, 1 topic document and indexes, in pages of 7
        frames = [item.message.message().header.frame_id for item in got]
        assert in_feed_order(frames, server) == [str(i) for i in range(20)]
        assert {item.message.robot_id for item in got} == {"robot1"}
        assert all(item.message.topic == "/odom" for item in got)
        resume_at = got[9].seq

        # a new follower from a saved sequence yields only what came after it, each once
        again = ChangesFollower(url, selector={"topic": "/odom"}, since=resume_at)
        later = [i.message.message().header.frame_id for i in again.poll()]
        assert in_feed_order(later, server) == in_feed_order(frames[10:], server)

        # follow(): across a server outage (reconnects with back-off), new messages arrive once
        stop = threading.Event()
        arrived: queue.Queue = queue.Queue()
        follower = ChangesFollower(url, selector={"topic": "/odom"}, since=got[-1].seq,
                                   backoff_min=0.2, backoff_max=1.0)

        def run():
            for item in follower.follow(stop):
                arrived.put(item.message.message().header.frame_id)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        server.stop()
        wait_until(lambda: "unreachable" in follower.last_error, LONG, what="the outage noticed")
        server.start()
        with open_store(url) as store:
            record(store, "robot2", 20, 5)
        frames = [arrived.get(timeout=LONG) for _ in range(5)]
        assert in_feed_order(frames, server) == [str(i) for i in range(20, 25)]
        stop.set()
        thread.join(timeout=LONG)
        assert not thread.is_alive()
        assert arrived.empty() and follower.last_error == ""
    finally:
        server.stop()


@pytest.mark.db
def test_credentials_never_shown(tmp_path):
    secret = "s3cret-Passw0rd"
    follower = ChangesFollower(f"http://reader:{secret}@127.0.0.1:9/fleet", timeout=2.0)
    assert secret not in follower.shown and "reader" in follower.shown
    with pytest.raises(ReplicationUnavailable) as caught:
        follower.poll()
    assert secret not in str(caught.value)
    # a database that answers: the URL in errors is redacted too
    with PouchDBServer(tmp_path / "db") as server:
        missing = ChangesFollower(server.url.replace("http://", f"http://reader:{secret}@")
                                  + "/missing")
        with pytest.raises(ReplicationError) as caught:
            missing.poll()
        assert secret not in str(caught.value) and "missing" in str(caught.value)
        assert requests.get(server.url, timeout=30).ok
