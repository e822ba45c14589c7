"""pytest fixtures with real components, loaded by the workspace's root conftest.py.

Fixtures (all tear down what they started, by process id):
- `roscore` (session): a real roscore on a free port; ROS_MASTER_URI etc. set in os.environ.
- `rospy_node` (session): this test process as a rospy node (for publishing and calling services).
- `roslaunch` (function): `roslaunch("pkg", "file.launch", arg=value)`, `roslaunch(path)` or
  `roslaunch.node("pkg", "exe", params={...}, remap={...})`; returns a started `RosLaunch` whose
  `wait_for_topics/services/nodes` wait on the master with a timeout.
- `couchdb_server`, `mongodb_server` (session): shared real database servers;
  `couchdb_url`, `mongodb_url` (function): a fresh database on them;
  `db_url` (function, parametrised): the same test against both backends.
- `own_couchdb_server`, `own_mongodb_server`, `own_db_server` (function; the last parametrised):
  a private server that the test may stop and restart (outage tests).
- `xvfb_display` (session): a virtual X display for rviz screenshots.
- `workspace_root`: the repository root.
Markers: `ros` (needs roscore), `db` (needs a database server), `rviz`, `slow`.
"""
import os
import uuid
import xmlrpc.client
from pathlib import Path
from typing import List

import pytest

from ros_harness.errors import HarnessError
from ros_harness.processes import (
    ManagedProcess,
    MongoWireServer,
    PouchDBServer,
    RosCore,
    RosLaunch,
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

    rospy.init_node("pytest_client", anonymous=True, disable_signals=True)
    yield rospy
    rospy.signal_shutdown("tests finished")


class Launcher:
    """Starts launches for one test and stops them all at its end."""

    def __init__(self, core: RosCore, log_dir: Path):
        self.core = core
        self.log_dir = log_dir
        self.launched: List[RosLaunch] = []
        self.params_before = set(_param_names(core.uri))

    def __call__(self, package_or_path: str, launch_file: str = "", **args) -> RosLaunch:
        target = [package_or_path, launch_file] if launch_file else [package_or_path]
        return self._start(RosLaunch(target, master_uri=self.core.uri, log_dir=self.log_dir,
                                     args=args, env=self.core.env()))

    def node(self, package: str, executable: str, **options) -> RosLaunch:
        return self._start(RosLaunch.node(package, executable, master_uri=self.core.uri,
                                          log_dir=self.log_dir, env=self.core.env(), **options))

    def _start(self, launch: RosLaunch) -> RosLaunch:
        self.launched.append(launch)
        return launch.start()

    def stop_all(self) -> None:
        """Stop every launch, then delete the parameters they set: the master outlives the test,
        and a node started later under the same name must not read this test's private params."""
        for launch in reversed(self.launched):
            launch.stop()
        master = xmlrpc.client.ServerProxy(self.core.uri)
        for name in set(_param_names(self.core.uri)) - self.params_before:
            master.deleteParam("/pytest_launcher", name)


def _param_names(master_uri: str) -> List[str]:
    code, message, names = xmlrpc.client.ServerProxy(master_uri).getParamNames("/pytest_launcher")
    if code != 1:
        raise HarnessError(f"cannot list parameters of {master_uri}: {message}")
    return names


@pytest.fixture
def roslaunch(roscore, tmp_path):
    launcher = Launcher(roscore, tmp_path / "launch")
    yield launcher
    launcher.stop_all()


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
def xvfb_display(tmp_path_factory):
    number = next(n for n in range(99, 200) if not Path(f"/tmp/.X{n}-lock").exists()
                  and not Path(f"/tmp/.X11-unix/X{n}").exists())
    log = tmp_path_factory.mktemp("xvfb") / "xvfb.log"
    xvfb = ManagedProcess(["Xvfb", f":{number}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                          name="Xvfb", log_path=log).start()
    wait_until(lambda: Path(f"/tmp/.X11-unix/X{number}").exists(), 20, what="Xvfb socket",
               check=xvfb.check_alive)
    yield f":{number}"
    xvfb.stop(timeout=5)
