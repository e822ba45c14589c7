"""pytest fixtures with real components, loaded by the workspace's root conftest.py.

Fixtures (all tear down what they started, by process id):
- `roscore` (session): a real roscore on a free port; ROS_MASTER_URI etc. set in os.environ.
- `rospy_node` (session): this test process as a rospy node (for publishing and calling services).
- `roslaunch` (function): a `ros_harness.launching.LaunchSet`: `roslaunch("pkg", "file.launch",
  arg=value)`, `roslaunch(path)` or `roslaunch.node("pkg", "exe", params={...}, remap={...})`;
  returns a started `RosLaunch` whose `wait_for_topics/services/nodes` wait on the master with a
  timeout. At the test's end every launch stops and the parameters they set are deleted.
- `couchdb_server`, `mongodb_server` (session): shared real database servers;
  `couchdb_url`, `mongodb_url` (function): a fresh database on them;
  `db_url` (function, parametrised): the same test against both backends.
- `own_couchdb_server`, `own_mongodb_server`, `own_db_server` (function; the last parametrised):
  a private server that the test may stop and restart (outage tests).
- `apache_couchdb` (session): a real Apache CouchDB 3 node from ../shared/couchdb or
  $SHARED_COUCHDB_DIR (skipped with the reason where that folder is absent);
  `apache_couchdb_url` (function): a fresh database on it, created by the admin, as the URL of
  its *member* account;
  `couch_server` (parametrised "pouchdb", "apache"): the shared server of each kind (both have
  `.url` for the test's own requests and `.database_url(name)` for the product);
  `couchdb_cluster` (function): a real 3-node cluster the test may kill nodes of and restart.
- `xvfb_display` (session): a virtual X display for rviz screenshots.
- `workspace_root`: the repository root.
Markers: `ros` (needs roscore), `db` (needs a database server), `rviz`, `slow`.
"""
import os
import uuid
from pathlib import Path

import pytest

from ros_harness.apache_couchdb import ApacheCouchDB, CouchDBCluster, missing_reason, shared_couchdb_dir
from ros_harness.errors import HarnessError
from ros_harness.launching import LaunchSet
from ros_harness.processes import (
    START_TIMEOUT,
    ManagedProcess,
    MongoWireServer,
    PouchDBServer,
    RosCore,
    wait_until,
)

MARKERS = {
    "ros": "starts a real roscore and ROS nodes",
    "db": "starts a real database server",
    "rviz": "runs rviz under Xvfb",
    "slow": "takes more than about 30 s",
}


def pytest_configure(config):
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")


@pytest.fixture(scope="session")
def workspace_root(pytestconfig) -> Path:
    return Path(os.environ.get("ROBOT_WS_ROOT", str(pytestconfig.rootpath)))


@pytest.fixture(scope="session")
def shared_data_dir(workspace_root) -> Path:
    """../shared/data beside the clone (real maps, corpora); tests that need it skip without it."""
    path = Path(os.environ.get("SHARED_DATA_DIR", str(workspace_root.parent / "shared" / "data")))
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path}")
    return path


@pytest.fixture(scope="session")
def roscore(tmp_path_factory):
    core = RosCore(log_dir=tmp_path_factory.mktemp("ros_logs"))
    saved = {key: os.environ.get(key) for key in core.env()}
    core.start()
    os.environ.update({key: value for key, value in core.env().items() if key in saved})
    yield core
    core.stop()
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@pytest.fixture(scope="session")
def rospy_node(roscore):
    import rospy

    from robot_common.ros_node import shut_down_rospy

    rospy.init_node("pytest_client", anonymous=True, disable_signals=True)
    yield rospy
    # a pytest-xdist worker waits for the others after this: nothing may keep spinning
    shut_down_rospy("tests finished")


@pytest.fixture
def roslaunch(roscore, tmp_path):
    launches = LaunchSet(roscore, tmp_path / "launch")
    yield launches
    launches.stop_all()


@pytest.fixture(scope="session")
def couchdb_server(tmp_path_factory):
    server = PouchDBServer(tmp_path_factory.mktemp("couchdb")).start()
    yield server
    server.stop()


@pytest.fixture(scope="session")
def mongodb_server(tmp_path_factory):
    server = MongoWireServer(tmp_path_factory.mktemp("mongodb")).start()
    yield server
    server.stop()


def _fresh_name() -> str:
    return "test_" + uuid.uuid4().hex[:12]


@pytest.fixture
def couchdb_url(couchdb_server) -> str:
    return couchdb_server.database_url(_fresh_name())


@pytest.fixture
def mongodb_url(mongodb_server) -> str:
    return mongodb_server.database_url(_fresh_name())


@pytest.fixture(params=["couchdb", "mongodb"])
def db_url(request) -> str:
    return request.getfixturevalue(f"{request.param}_url")


@pytest.fixture
def own_couchdb_server(tmp_path):
    """A private pouchdb-server the test may stop and restart (data survives restarts)."""
    server = PouchDBServer(tmp_path / "couchdb").start()
    yield server
    server.stop()


@pytest.fixture
def own_mongodb_server(tmp_path):
    """A private nx-27017 server the test may stop and restart (data survives restarts)."""
    server = MongoWireServer(tmp_path / "mongodb").start()
    yield server
    server.stop()


@pytest.fixture(params=["couchdb", "mongodb"])
def own_db_server(request):
    """A private server of each kind; `.database_url(name)` gives a database URL on it."""
    return request.getfixturevalue(f"own_{request.param}_server")


@pytest.fixture(scope="session")
def shared_couchdb(workspace_root) -> Path:
    """The real Apache CouchDB release and scripts (../shared/couchdb); skips where absent."""
    path = shared_couchdb_dir(workspace_root)
    reason = missing_reason(path)
    if reason:
        pytest.skip(reason)
    return path


@pytest.fixture(scope="session")
def apache_couchdb(shared_couchdb, tmp_path_factory):
    """One real Apache CouchDB node for the whole run (one database per test)."""
    server = ApacheCouchDB(shared_couchdb, tmp_path_factory.mktemp("apache_couchdb")).start()
    yield server
    server.stop()


@pytest.fixture
def apache_couchdb_url(apache_couchdb) -> str:
    return apache_couchdb.database_url(_fresh_name())


@pytest.fixture(params=["pouchdb", "apache"])
def couch_server(request):
    """The shared CouchDB-API server of each kind: pouchdb-server, then the real Apache CouchDB."""
    return request.getfixturevalue("couchdb_server" if request.param == "pouchdb" else "apache_couchdb")


@pytest.fixture
def couchdb_cluster(shared_couchdb, tmp_path):
    """A real 3-node Apache CouchDB cluster of this test's own (it may kill and restart nodes)."""
    cluster = CouchDBCluster(shared_couchdb, tmp_path / "couchdb_cluster").start()
    yield cluster
    cluster.stop()


@pytest.fixture(scope="session")
def xvfb_display(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("xvfb")
    xvfb, number = _start_xvfb(log_dir)
    yield f":{number}"
    xvfb.stop(timeout=5)


def _start_xvfb(log_dir: Path):
    """Xvfb on the first free display number. Parallel test workers may pick the same number at
    once: Xvfb itself takes the display's lock file, and the loser exits, so try the next one."""
    for number in range(99, 200):
        socket = Path(f"/tmp/.X11-unix/X{number}")
        if Path(f"/tmp/.X{number}-lock").exists() or socket.exists():
            continue
        xvfb = ManagedProcess(["Xvfb", f":{number}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                              name="Xvfb", log_path=log_dir / f"xvfb_{number}.log").start()
        if _wait_for_display(xvfb, socket):
            return xvfb, number
    raise HarnessError("no free X display number between :99 and :199")


def _wait_for_display(xvfb: ManagedProcess, socket: Path) -> bool:
    """True once Xvfb serves the display; False when it exited (the display was taken)."""
    try:
        wait_until(lambda: socket.exists() or not xvfb.alive, START_TIMEOUT, what="Xvfb socket")
    except TimeoutError:
        xvfb.stop(timeout=5)
        raise
    return xvfb.alive
