"""A member password holding '@', '/', ':' and other characters URLs treat specially works through
every path to a real Apache CouchDB (ros_harness `apache_couchdb`; skipped where ../shared/couchdb
is absent): the credentials file, the environment and a percent-encoded URL, for the changes
follower and the CLI; fleet.launch's direct default and `local_db:=true` (the replicator); and a
replication that cannot log in shows ERROR on /diagnostics with the server's reason, the password
never shown."""
import os
import subprocess
import sys
import uuid
from urllib.parse import quote

import pytest
import requests
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from std_msgs.msg import String

from ros_harness import PouchDBServer, wait_for_subscriber, wait_until
from ros_mongo import open_store
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.urls import PASSWORD_ENV, USER_ENV, with_credentials

pytestmark = pytest.mark.db
LONG = 120.0
USER = "fleet_member"
HARD = "a@b/c:d?e#f%41g h!'\"~"  # every character a URL parser may split at


class Central:
    """A database on the real node whose members include USER (password HARD)."""

    def __init__(self, server, tmp_path):
        self.name = "fleet_" + uuid.uuid4().hex[:10]
        server.admin_request("PUT", f"/_users/org.couchdb.user:{USER}",
                             {"name": USER, "password": HARD, "roles": [], "type": "user"},
                             ok=(201, 202, 409))
        server.create_database(self.name)
        server.admin_request("PUT", f"/{self.name}/_security",
                             {"admins": {"names": [], "roles": []},
                              "members": {"names": [server.member[0], USER], "roles": []}})
        self.plain = f"{server.plain_url()}/{self.name}"  # password-free
        self.admin = server.admin_database_url(self.name)
        self.encoded = self.plain.replace("://", f"://{USER}:{quote(HARD, safe='')}@")
        self.credentials = tmp_path / "central.credentials"
        self.credentials.write_text(f"{USER}:{HARD}\n")

    def count(self, kind="message"):
        try:
            rows = requests.get(self.admin + "/_all_docs", params={"include_docs": "true"},
                                timeout=30).json()["rows"]
        except (requests.RequestException, ValueError, KeyError):
            return -1
        return sum(1 for row in rows if row["doc"].get("kind") == kind)


@pytest.fixture
def central(apache_couchdb, tmp_path):
    return Central(apache_couchdb, tmp_path)


def test_the_follower_and_the_cli_log_in_through_file_environment_and_encoded_url(central):
    with open_store(with_credentials(central.plain, credentials_file=str(central.credentials))) as store:
        for index in range(3):
            store.insert_message("/chatter", String(data=str(index)), robot_id="r1")
    environ = {USER_ENV: USER, PASSWORD_ENV: HARD}
    for url in (with_credentials(central.plain, credentials_file=str(central.credentials)),
                with_credentials(central.plain, environ=environ), central.encoded):
        follower = ChangesFollower(url)
        try:
            got = sorted(item.message.message().data for item in follower.poll())
        finally:
            follower.close()
        assert got == ["0", "1", "2"]
    cli = [sys.executable, "-c", "import sys; from ros_mongo.cli import main; sys.exit(main())", "info"]
    runs = [subprocess.run(cli + ["--db-url", central.plain, "--db-credentials-file",
                                  str(central.credentials)], capture_output=True, text=True, timeout=120),
            subprocess.run(cli + ["--db-url", central.plain], capture_output=True, text=True,
                           timeout=120, env=dict(os.environ, **environ))]
    for run in runs:
        assert run.returncode == 0 and "/chatter" in run.stdout, run.stderr
        assert HARD not in run.stdout + run.stderr and quote(HARD, safe="") not in run.stdout + run.stderr


class Diagnostics:
    """The replicator's latest status on /diagnostics."""

    def __init__(self, robot_id):
        self.name, self.status = f"ros_mongo_replicator: {robot_id}", None
        self.subscriber = rospy.Subscriber("/diagnostics", DiagnosticArray, self._receive)

    def _receive(self, msg):
        for status in msg.status:
            if status.name == self.name:
                self.status = status

    def level(self):
        return None if self.status is None else self.status.level

    def text(self):
        status = self.status
        return "" if status is None else status.message + " " + " ".join(v.value for v in status.values)


def _send(publisher, count, recorder="/ros_mongo_server"):
    wait_for_subscriber(publisher, recorder, LONG)
    for index in range(count):
        msg = Odometry()
        msg.header.frame_id = str(index)
        publisher.publish(msg)
        rospy.sleep(0.01)  # the publisher's pace, not synchronisation


@pytest.mark.ros
@pytest.mark.parametrize("local_db", [False, True], ids=["direct", "local_db"])
def test_fleet_launch_records_into_central_with_the_hard_password(roslaunch, rospy_node, workspace_root,
                                                                  central, tmp_path, local_db):
    robot_id = f"robot_{uuid.uuid4().hex[:6]}"
    args = dict(central_url=central.plain, central_credentials_file=str(central.credentials),
                robot_id=robot_id, topics="[/odom]", spool_path=str(tmp_path / "spool"))
    store = PouchDBServer(tmp_path / "robot").start() if local_db else None
    try:
        if store:
            args.update(local_db="true", local_db_server="false", local_db_port=store.port)
            diagnostics = Diagnostics(robot_id)
        roslaunch(str(workspace_root / "launch" / "fleet.launch"), **args)
        publisher = rospy.Publisher("/odom", Odometry, queue_size=100)
        _send(publisher, 20)
        wait_until(lambda: central.count() == 20, LONG, what="20 messages central")
        if store:
            wait_until(lambda: diagnostics.level() == DiagnosticStatus.OK, LONG, what="replicator OK")
            diagnostics.subscriber.unregister()
        publisher.unregister()
    finally:
        if store:
            store.stop()


@pytest.mark.ros
def test_a_replication_that_cannot_log_in_shows_error_with_the_reason(roslaunch, rospy_node,
                                                                      workspace_root, central, tmp_path):
    wrong = HARD + "x"
    central.credentials.write_text(f"{USER}:{wrong}\n")
    robot_id = f"robot_{uuid.uuid4().hex[:6]}"
    diagnostics = Diagnostics(robot_id)
    with PouchDBServer(tmp_path / "robot") as store:
        roslaunch(str(workspace_root / "launch" / "fleet.launch"), central_url=central.plain,
                  central_credentials_file=str(central.credentials), robot_id=robot_id,
                  topics="[/odom]", local_db="true", local_db_server="false", local_db_port=store.port,
                  spool_path=str(tmp_path / "spool"))
        wait_until(lambda: diagnostics.level() == DiagnosticStatus.ERROR, LONG, what="ERROR on /diagnostics")
        text = diagnostics.text()
        assert "Name or password is incorrect." in text, text
        for secret in (wrong, quote(wrong, safe=""), HARD):
            assert secret not in text
    diagnostics.subscriber.unregister()
