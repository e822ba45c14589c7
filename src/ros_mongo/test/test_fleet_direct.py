"""The fleet default as users run it (launch/fleet.launch without local_db): each robot's recorder
writes straight to the central CouchDB database, its spool the only buffer on the robot.

Real processes only: a central pouchdb-server behind ros_harness.fault_proxy answering as a real
Apache CouchDB 3 does for a database *member* account (`member`: creating the database answers 401,
indexes 500 error_saving_ddoc forbidden; `require_auth`: only the robots' credentials get in), real
roscores (one per robot), the recorders through roslaunch, and the fleet test publisher. The central
outage is the real central server stopped; one robot is restarted in the middle of it. What was
published is counted by the publishers; what central holds is read from central by content.
The same fleet also records into a real 3-node Apache CouchDB cluster (ros_harness
`couchdb_cluster`), one node of it killed and restarted.
"""
from pathlib import Path

import pytest
import requests
from fleet_helpers import FleetRobot, all_docs, content, holds, messages
from ros_mongo_samples import serialized
from std_msgs.msg import String

from ros_harness import FaultProxy, LaunchSet, PouchDBServer, RosCore, wait_for_subscriber, wait_until
from ros_mongo import TopicInfo, make_record, open_store
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.records import split_time

LONG = 300.0  # seconds: generous, the machine is busy
CREDENTIALS = "robot:s3cret"


def central_counts(admin_url):
    """Messages per robot in central, read as an admin (past the proxy)."""
    try:
        found = {}
        for doc in messages(all_docs(admin_url)):
            found[doc["robot_id"]] = found.get(doc["robot_id"], 0) + 1
        return found
    except (requests.RequestException, ValueError, KeyError):
        return {}


class DirectRobot(FleetRobot):
    """One robot: its own roscore and fleet.launch in its default (direct) form."""

    def __init__(self, index, work: Path, central_url, credentials_file, workspace_root):
        self.robot_id = f"robot{index}"
        self.work = work / self.robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.launches = LaunchSet(self.core, self.work / "launch")
        self.args = dict(central_url=central_url, robot_id=self.robot_id,
                         central_credentials_file=str(credentials_file),
                         topics="[/odom, /camera/rgb/image_raw]",
                         spool_path=str(self.work / "recorder.spool"))
        self.launch_file = str(workspace_root / "launch" / "fleet.launch")
        self.launch = self.launches(self.launch_file, **self.args)
        self.publisher = None

    def restart(self):
        self.launches.stop(self.launch)
        self.launch = self.launches(self.launch_file, **self.args)

    def spooled_bytes(self):
        path = self.work / "recorder.spool"
        return path.stat().st_size if path.exists() else 0



@pytest.mark.ros
@pytest.mark.db
def test_direct_fleet_keeps_each_message_once_through_a_central_outage_and_a_robot_restart(
        tmp_path, workspace_root):
    count, rate, hold = 200, 60.0, 60
    central = PouchDBServer(tmp_path / "central").start()
    admin_url = central.database_url("fleet")
    assert requests.put(admin_url, timeout=30).status_code == 201  # the admin creates the database
    credentials = tmp_path / "central.credentials"
    credentials.write_text(CREDENTIALS + "\n")
    proxy = FaultProxy(central.url, tmp_path / "proxy").start()
    proxy.set(member=True, require_auth=CREDENTIALS)
    robots = []
    try:
        central_url = proxy.database_url("fleet")
        robots = [DirectRobot(i, tmp_path, central_url, credentials, workspace_root) for i in (1, 2)]
        for robot in robots:
            robot.launch.wait_for_subscribers(["/odom", "/camera/rgb/image_raw"], timeout=LONG)
            robot.publish(count, rate, hold_at=hold)
        wait_until(lambda: holds(admin_url, 30 * len(robots))
                   and all(central_counts(admin_url).get(r.robot_id, 0) >= 30 for r in robots), LONG,
                   what="30 messages of each robot central")

        central.stop()  # the central outage: every robot spools
        for robot in robots:
            robot.go_file.touch()  # the rest of the stream comes while central is down
        wait_until(lambda: all(r.spooled_bytes() > 0 for r in robots), LONG, what="both robots spooling")
        # robot1 finishes publishing and restarts in the middle of the outage: its new recorder
        # finds the spool the old one left
        wait_until(lambda: not robots[0].publisher.alive, LONG, what="robot1 published everything")
        robots[0].restart()
        robots[0].launch.wait_for_subscribers(["/odom"], timeout=LONG)
        assert robots[0].spooled_bytes() > 0  # what robot1 recorded is on its disk only
        central.start()

        wait_until(lambda: not any(r.publisher.alive for r in robots), LONG, what="all published")
        published = {r.robot_id: r.published() for r in robots}
        for sent in published.values():
            assert sent == {"/odom": count, "/camera/rgb/image_raw": count // 10}
        expected = sum(sum(p.values()) for p in published.values())
        wait_until(lambda: holds(admin_url, expected) and sum(central_counts(admin_url).values()) >= expected,
                   LONG,
                   what=f"{expected} messages central")

        docs = all_docs(admin_url)
        assert [d["_id"] for d in docs if d.get("_conflicts")] == []
        contents = [content(d) for d in messages(docs)]
        want = {(r.robot_id, topic, i) for r in robots
                for topic, step in (("/odom", 1), ("/camera/rgb/image_raw", 10))
                for i in range(0, count, step)}
        assert len(contents) == len(set(contents)) == expected  # nothing twice
        assert set(contents) == want                             # nothing lost
        image = next(d for d in messages(docs) if d["topic"] == "/camera/rgb/image_raw")
        raw = requests.get(f"{admin_url}/{image['_id']}/raw", timeout=30)
        assert raw.status_code == 200 and len(raw.content) == image["size"]
        # a learner reading central (the changes follower, as traffic_gp and igmm_layers do) gets
        # every robot's odometry once, through the proxy with the robots' account
        follower = ChangesFollower(central_url.replace("://", f"://{CREDENTIALS}@"),
                                   selector={"type": {"$in": ["nav_msgs/Odometry"]}})
        learned = []
        while True:
            learned += [(item.message.robot_id, item.message.message().header.frame_id)
                        for item in follower.poll()]
            if follower.caught_up:
                break
        assert sorted(learned) == sorted((r.robot_id, str(i)) for r in robots for i in range(count))
        # the member account could not create indexes or the database, and did not need to
        assert proxy.answered("member") >= 1
        assert not any(d["_id"].startswith("_design/") for d in docs)
    finally:
        for robot in robots:
            robot.close()
        proxy.stop()
        central.stop()


@pytest.mark.ros
@pytest.mark.db
@pytest.mark.slow
def test_direct_fleet_on_a_real_couchdb_cluster_keeps_every_message_through_a_node_killed_and_restarted(
        couchdb_cluster, tmp_path, workspace_root):
    """Two robots record through node 1 of a real 3-node Apache CouchDB cluster (n = 3) as a
    database member; node 2 is killed (SIGKILL) while they publish, and started again: writes keep
    their quorum (2 of 3 copies), and every message is there once, read through each node. Then
    with two nodes down the server accepts writes below the quorum (202): still stored, each once."""
    count, rate, hold = 200, 60.0, 60
    cluster = couchdb_cluster
    cluster.create_database("fleet")
    user, password = cluster.member
    credentials = tmp_path / "central.credentials"
    credentials.write_text(f"{user}:{password}\n")
    robots = []
    try:
        central_url = cluster.plain_url(0) + "/fleet"   # password-free: the credentials file has it
        robots = [DirectRobot(i, tmp_path, central_url, credentials, workspace_root) for i in (1, 2)]
        for robot in robots:
            robot.launch.wait_for_subscribers(["/odom", "/camera/rgb/image_raw"], timeout=LONG)
            robot.publish(count, rate, hold_at=hold)
        node1 = cluster.admin_database_url("fleet", node=0)
        wait_until(lambda: all(central_counts(node1).get(r.robot_id, 0) >= 30 for r in robots), LONG,
                   what="30 messages of each robot central")
        cluster.kill_node(1)
        for robot in robots:
            robot.go_file.touch()  # the rest of the stream comes while node 2 is down
        wait_until(lambda: not any(r.publisher.alive for r in robots), LONG, what="all published")
        published = {r.robot_id: r.published() for r in robots}
        expected = sum(sum(p.values()) for p in published.values())
        wait_until(lambda: sum(central_counts(node1).values()) >= expected, LONG,
                   what=f"{expected} messages central with node 2 down")
        cluster.start()  # starts the killed node only

        want = {(r.robot_id, topic, i) for r in robots
                for topic, step in (("/odom", 1), ("/camera/rgb/image_raw", 10))
                for i in range(0, count, step)}
        assert expected == len(want)
        for node in range(3):
            url = cluster.admin_database_url("fleet", node=node)
            wait_until(lambda url=url: sum(central_counts(url).values()) >= expected, LONG,
                       what=f"{expected} messages through node {node + 1}")
            docs = all_docs(url)
            assert [d["_id"] for d in docs if d.get("_conflicts")] == []
            contents = [content(d) for d in messages(docs)]
            assert len(contents) == len(set(contents)) and set(contents) == want  # once, none lost
        assert not any(d["_id"].startswith("_design/") for d in docs)  # a member wrote no index

        # two nodes down: a write reaches one copy of three, below the quorum (202 Accepted); the
        # store reads its documents back before it counts them stored; the others get them later
        cluster.kill_node(1)
        cluster.kill_node(2)
        probe = requests.post(node1 + "/_bulk_docs", json={"docs": [{"_id": "quorum-probe"}]}, timeout=LONG)
        assert probe.status_code == 202 and probe.json()[0].get("accepted") is True
        notes = [make_record("/notes", String, serialized(String(data=f"n{i}")), receive=split_time(2e9 + i),
                             session_id="quorum") for i in range(50)]
        with open_store(cluster.member_url("fleet", node=0), warn_password=False) as store:
            store.put_topic(TopicInfo.of_class("/notes", String))
            assert store.insert_records(notes) == 50
        cluster.start()
        node3 = cluster.admin_database_url("fleet", node=2)
        with open_store(node3, warn_password=False) as store:
            wait_until(lambda: [m.message().data for m in store.find_messages(topic="/notes")]
                       == [f"n{i}" for i in range(50)], LONG, what="the 50 notes through node 3")
    finally:
        for robot in robots:
            robot.close()


@pytest.mark.ros
@pytest.mark.db
def test_a_full_spool_loses_only_the_oldest_images_and_counts_each(roslaunch, diagnostics, rospy_node,
                                                                    workspace_root, tmp_path):
    """An outage longer than ~spool_max_mb holds (2 MB for 6 MB of images and 0.5 MB of
    odometry): every odometry message reaches central, images lose their oldest ones only, and
    the count dropped on /diagnostics is exactly what central misses."""
    import rospy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Image

    count, images_every = 200, 10
    central = PouchDBServer(tmp_path / "central").start()
    central_url = central.database_url("fleet")
    assert requests.put(central_url, timeout=30).status_code == 201
    central.stop()  # down before the robot records anything
    launch = roslaunch(str(workspace_root / "launch" / "fleet.launch"), central_url=central_url,
                       robot_id="robot_full", topics="[/odom, /camera/rgb/image_raw]", spool_max_mb="2",
                       spool_path=str(tmp_path / "recorder.spool"))
    odom_pub = rospy.Publisher("/odom", Odometry, queue_size=1000)
    image_pub = rospy.Publisher("/camera/rgb/image_raw", Image, queue_size=100)
    launch.wait_for_subscribers(["/odom", "/camera/rgb/image_raw"], timeout=LONG)
    for publisher in (odom_pub, image_pub):
        wait_for_subscriber(publisher, "/ros_mongo_server", LONG)
    pixels = bytes(i % 251 for i in range(640 * 480))
    for index in range(count):
        odom = Odometry()
        odom.header.frame_id = str(index)
        odom_pub.publish(odom)
        if index % images_every == 0:
            image = Image(height=480, width=640, encoding="mono8", step=640, data=pixels)
            image.header.frame_id = str(index)
            image_pub.publish(image)
        rospy.sleep(0.01)  # the publisher's pace, not synchronisation
    sent_images = count // images_every
    wait_until(lambda: diagnostics.count("received") == count + sent_images, LONG, what="all received")
    wait_until(lambda: diagnostics.count("queued") == 0 and diagnostics.count("dropped") > 0, LONG,
               what="everything spooled, images dropped")
    dropped = diagnostics.count("dropped")
    per_topic = {k: int(v) for k, v in diagnostics.values.items() if k.startswith("dropped ")}
    assert per_topic == {"dropped /camera/rgb/image_raw": dropped}  # only the stated topic
    assert float(diagnostics.values["spool_mb"]) <= 2.0
    assert 0 < dropped < sent_images

    central.start()
    wait_until(lambda: diagnostics.count("spool_pending") == 0
               and diagnostics.count("stored") == count + sent_images - dropped, LONG, what="spool drained")
    docs = messages(all_docs(central_url))
    odometry = sorted(int(d["msg"]["header"]["frame_id"]) for d in docs if d["topic"] == "/odom")
    images = sorted(int(d["msg"]["header"]["frame_id"]) for d in docs if d["topic"] != "/odom")
    assert odometry == list(range(count))                                   # nothing else lost
    kept = sent_images - dropped
    assert images == list(range((sent_images - kept) * images_every, count, images_every))  # the newest
    central.stop()
    odom_pub.unregister()
    image_pub.unregister()
