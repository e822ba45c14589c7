"""ros_mongo.changes: following a database's `_changes` feed (real pouchdb-server, no ROS)."""
import queue
import threading

import pytest
import requests
from nav_msgs.msg import Odometry
from std_msgs.msg import String

from ros_harness import PouchDBServer, wait_until
from ros_mongo import open_store
from ros_mongo.changes import ChangesFollower, matches_selector
from ros_mongo.replication import ReplicationError, ReplicationUnavailable

LONG = 120.0


def record(store, robot_id, first, count):
    """Odometry (frame_id = index) and one String per 5 messages, as the recorder stores them."""
    for index in range(first, first + count):
        odom = Odometry()
        odom.header.frame_id = str(index)
        store.insert_message("/odom", odom, robot_id=robot_id)
        if index % 5 == 0:
            store.insert_message("/chatter", String(data=str(index)), robot_id=robot_id)


def test_selector_rules():
    doc = {"kind": "message", "type": "nav_msgs/Odometry", "topic": "/odom", "robot_id": None}
    assert matches_selector(doc, {"type": "nav_msgs/Odometry"})
    assert matches_selector(doc, {"topic": {"$in": ["/odom", "/scan"]}, "kind": {"$eq": "message"}})
    assert not matches_selector(doc, {"topic": {"$nin": ["/odom"]}})
    assert not matches_selector(doc, {"topic": {"$ne": "/odom"}})
    assert matches_selector(doc, {"robot_id": {"$exists": False}, "topic": {"$exists": True}})
    assert not matches_selector(doc, {"session_id": {"$in": [None]}})
    with pytest.raises(ReplicationError, match=r"\$regex"):
        ChangesFollower("http://127.0.0.1:1/db", selector={"topic": {"$regex": "o"}})


@pytest.mark.db
def test_follows_selected_messages_resumes_from_a_sequence_and_survives_an_outage(tmp_path):
    server = PouchDBServer(tmp_path / "central").start()
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
        assert [item.message.message().header.frame_id for item in got] == [str(i) for i in range(20)]
        assert {item.message.robot_id for item in got} == {"robot1"}
        assert all(item.message.topic == "/odom" for item in got)
        resume_at = got[9].seq

        # a new follower from a saved sequence yields only what came after it
        again = ChangesFollower(url, selector={"topic": "/odom"}, since=resume_at)
        later = again.poll()
        assert [i.message.message().header.frame_id for i in later] == [str(i) for i in range(10, 20)]

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
        assert frames == [str(i) for i in range(20, 25)]
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
