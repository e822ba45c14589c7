"""An https central signed by a private CA: a real Apache CouchDB node configured for TLS here
([ssl] with a server certificate made by `openssl` in the test's tmp dir, signed by a CA made
there too; skipped where ../shared/couchdb or openssl is absent). Direct recording (the store the
recorder writes through), the changes follower, the CLI and a robot store's push replication reach it
with the CA file; without it every path refuses with the certificate failure, the password never
shown."""
import shutil
import subprocess
import sys

import pytest
from std_msgs.msg import String

from ros_harness import ApacheCouchDB, PouchDBServer, wait_until
from ros_harness.apache_couchdb import _free_base
from ros_mongo import open_store
from ros_mongo.errors import StoreRefused
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.fleet.replication import CouchDatabase, PendingTracker, PushReplication, ReplicationRefused

pytestmark = pytest.mark.db
LONG = 120.0


def _openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def private_ca(folder):
    """(CA certificate, server certificate, server key) for 127.0.0.1, in `folder`."""
    folder.mkdir()
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
             "-days", "2", "-subj", "/CN=ros_mongo test CA", cwd=folder)
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
             "-subj", "/CN=127.0.0.1", cwd=folder)
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    _openssl("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
             "-CAcreateserial", "-out", "server.pem", "-days", "2", "-extfile", "san.ext", cwd=folder)
    return folder / "ca.pem", folder / "server.pem", folder / "server.key"


@pytest.fixture
def tls_central(shared_couchdb, tmp_path):
    """A real CouchDB node answering https on its own port with a certificate of a private CA."""
    if not shutil.which("openssl"):
        pytest.skip("openssl is not installed: cannot make the test's private CA")
    ca, cert, key = private_ca(tmp_path / "pki")
    server = ApacheCouchDB(shared_couchdb, tmp_path / "central").start()
    try:
        https_port = _free_base((0,))
        for name, value in (("port", str(https_port)), ("cert_file", str(cert)),
                            ("key_file", str(key)), ("enable", "true")):
            server.set_config("ssl", name, value)
        server.restart()  # the https listener starts with the node
        server.create_database("fleet")
        user, password = server.member
        server.https_url = f"https://{user}:{password}@127.0.0.1:{https_port}/fleet"
        server.ca = str(ca)
        yield server
    finally:
        server.stop()


def test_https_central_with_a_private_ca_for_recording_following_and_replication(
        tls_central, tmp_path, monkeypatch):
    url, ca = tls_central.https_url, tls_central.ca
    password = tls_central.member[1]
    # direct recording: the store the recorder writes through
    with pytest.raises(StoreRefused, match="CERTIFICATE_VERIFY_FAILED") as refused:
        open_store(url)
    assert password not in str(refused.value)
    with open_store(url, tls_ca_file=ca) as store:
        for index in range(3):
            store.insert_message("/chatter", String(data=str(index)), robot_id="direct")
    # the changes follower
    follower = ChangesFollower(url, tls_ca_file=ca)
    try:
        assert sorted(item.message.message().data for item in follower.poll()) == ["0", "1", "2"]
    finally:
        follower.close()
    with pytest.raises(ReplicationRefused, match="CERTIFICATE_VERIFY_FAILED"):
        ChangesFollower(url).poll()
    # the CLI, its password from a file
    user = tls_central.member[0]
    credentials = tmp_path / "credentials"
    credentials.write_text(f"{user}:{password}\n")
    plain = url.replace(f"{user}:{password}@", "")
    cli = [sys.executable, "-c", "import sys; from ros_mongo.cli import main; sys.exit(main())", "info",
           "--db-url", plain, "--db-credentials-file", str(credentials)]
    run = subprocess.run(cli + ["--db-tls-ca-file", ca], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "/chatter" in run.stdout, run.stderr
    run = subprocess.run(cli, capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "CERTIFICATE_VERIFY_FAILED" in run.stderr and password not in run.stderr
    # replication: the robot's store (pouchdb-server, trusting the CA as node does) pushes; the
    # replicator's own checks (reachability, pending documents) go through the one client
    monkeypatch.setenv("NODE_EXTRA_CA_CERTS", ca)
    with PouchDBServer(tmp_path / "robot") as robot:
        local_url = robot.database_url("robot_data")
        with open_store(local_url) as store:
            for index in range(5):
                store.insert_message("/chatter", String(data=f"r{index}"), robot_id="robot1")
        local, central = CouchDatabase(local_url), CouchDatabase(url, tls_ca_file=ca)
        unverified = PushReplication.for_robot(local, CouchDatabase(url), "robot1")
        problem = unverified.central_problem()
        assert isinstance(problem, ReplicationRefused) and "CERTIFICATE_VERIFY_FAILED" in str(problem)
        assert password not in str(problem)
        replication = PushReplication.for_robot(local, central, "robot1")
        assert replication.central_problem() is None
        replication.start()
        tracker = PendingTracker(local, central, replication.spec, checkpoint_id=replication.doc_id)
        wait_until(lambda: tracker.poll().confirmed >= 5 + 1 and tracker.counts.pending == 0, LONG,
                   what="robot's messages and topic confirmed central over https")
        assert tracker.counts.error == ""
        with open_store(url, tls_ca_file=ca) as store:
            robot_data = [m.message().data for m in store.find_messages(topic="/chatter")
                          if m.robot_id == "robot1"]
        assert sorted(robot_data) == [f"r{i}" for i in range(5)]
        replication.stop()
