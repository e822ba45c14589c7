"""Start and stop real ROS and database processes, and wait on conditions instead of sleeping.

The database servers' command lines come from robot_common.db_servers (written there only).
Everything here is started in its own process session and stopped by process id (never by name),
with its output in a log file whose tail is quoted when something goes wrong.

Every wait here is on a condition (the master answers, a topic has a publisher, a port accepts
connections), bounded by a timeout that only limits how long a failure takes to show: the defaults
(START_TIMEOUT, WAIT_TIMEOUT) are generous enough for a 2-core machine whose cores are both busy
(scripts/cpu_hog.sh), so they cost nothing when things work and never decide a pass.
"""
import os
import signal
import socket
import subprocess
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple
from xml.sax.saxutils import quoteattr

from robot_common.db_servers import couchdb_server_command, mongodb_server_command
from ros_harness.errors import HarnessError, ProcessDied

__all__ = [
    "START_TIMEOUT",
    "WAIT_TIMEOUT",
    "STOP_TIMEOUT",
    "free_port",
    "wait_until",
    "ManagedProcess",
    "RosCore",
    "RosLaunch",
    "PouchDBServer",
    "MongoWireServer",
    "master_graph",
    "http_get_json",
]

#: Seconds a process (roscore, a database server, Xvfb) may take to come up on a loaded machine.
START_TIMEOUT = 90.0
#: Seconds a graph condition (topics, subscribers, services, nodes, a port closing) may take.
WAIT_TIMEOUT = 90.0
#: Seconds a stopped process may take to exit by itself (flushing, closing files) before SIGKILL.
STOP_TIMEOUT = 60.0


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_until(condition: Callable[[], object], timeout: float, *, interval: float = 0.05,
               what: str = "condition", check: Optional[Callable[[], None]] = None):
    """Poll `condition` until it returns a true value, and return that value.

    Args:
        condition: called repeatedly; exceptions it raises count as "not yet".
        timeout: seconds before giving up with TimeoutError naming `what`.
        interval: seconds between polls (grows to at most 0.5 s).
        check: called on every poll; raises to abort early (e.g. the process died).
    """
    deadline = time.monotonic() + timeout
    last_error = None
    while True:
        if check is not None:
            check()
        try:
            value = condition()
            if value:
                return value
        except Exception as err:  # noqa: BLE001 - any failure means "not ready yet"
            last_error = err
        if time.monotonic() >= deadline:
            detail = f" (last error: {last_error!r})" if last_error else ""
            raise TimeoutError(f"timed out after {timeout:.1f} s waiting for {what}{detail}")
        time.sleep(interval)
        interval = min(interval * 1.5, 0.5)


def wait_for_subscriber(publisher, node: str, timeout: float) -> None:
    """Wait until the rospy `publisher` is connected to the subscriber node `node` itself: other
    subscribers of its topic (one an earlier test left in this process, on the session's
    roscore) must not count, or messages go out before `node` listens."""
    def connected() -> bool:
        return any(getattr(link, "endpoint_id", None) == node
                   for link in list(publisher.impl.connections))
    wait_until(connected, timeout, what=f"{node} subscribed to {publisher.resolved_name}")


def _let_children_hear_sigint() -> None:
    """A background job of a non-interactive shell starts with SIGINT ignored, and children
    inherit an ignored signal: every stop() would then wait its whole timeout before SIGKILL.
    Python's own handler is reset to the default on exec, so installing it fixes the children."""
    if (signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            and threading.current_thread() is threading.main_thread()):
        signal.signal(signal.SIGINT, signal.default_int_handler)


class ManagedProcess:
    """A child process in its own session with its output in a log file."""

    def __init__(self, argv: Sequence[str], *, name: str, log_path: Path,
                 env: Optional[Mapping[str, str]] = None, cwd: Optional[Path] = None):
        self.argv = [str(a) for a in argv]
        self.name = name
        self.log_path = Path(log_path)
        self.env = dict(os.environ if env is None else env)
        self.cwd = cwd
        self.popen: Optional[subprocess.Popen] = None

    def start(self) -> "ManagedProcess":
        if self.alive:
            raise HarnessError(f"{self.name} is already running (pid {self.pid})")
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        _let_children_hear_sigint()
        with open(self.log_path, "ab") as log:
            self.popen = subprocess.Popen(self.argv, stdout=log, stderr=subprocess.STDOUT,
                                          stdin=subprocess.DEVNULL, env=self.env, cwd=self.cwd,
                                          start_new_session=True)
        return self

    @property
    def pid(self) -> Optional[int]:
        return self.popen.pid if self.popen else None

    @property
    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def log_tail(self, lines: int = 40) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def check_alive(self) -> None:
        """Raise ProcessDied (with the log tail) when the process has exited."""
        if self.popen is not None and self.popen.poll() is not None:
            raise ProcessDied(f"{self.name} exited with status {self.popen.returncode}; "
                              f"log {self.log_path}:\n{self.log_tail()}")

    def send_signal(self, signum: int) -> None:
        if self.alive:
            os.kill(self.popen.pid, signum)

    def stop(self, *, sig: int = signal.SIGINT, timeout: float = STOP_TIMEOUT) -> Optional[int]:
        """Send `sig`, wait up to `timeout`, then SIGKILL whatever is left of the process tree.

        Returns the exit status (None if the process was never started).
        """
        if self.popen is None:
            return None
        tree = _descendants(self.popen.pid)
        if self.popen.poll() is None:
            try:
                os.kill(self.popen.pid, sig)
                self.popen.wait(timeout=timeout)
            except (subprocess.TimeoutExpired, ProcessLookupError):
                pass
        self._kill_tree(tree)
        return self.popen.wait()

    def kill(self) -> None:
        """SIGKILL the process and every process it started, without any grace."""
        if self.popen is not None:
            self._kill_tree(_descendants(self.popen.pid))
            self.popen.wait()

    def _kill_tree(self, descendants: List[Tuple[int, int]]) -> None:
        """SIGKILL the process's session and `descendants` ((pid, start time) pairs; a pid
        whose start time changed is another process now). roslaunch starts each node in a
        session of its own: killing roslaunch's session alone would leave its nodes running,
        registered with the master, for the next test to meet."""
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        for pid, started in descendants:
            if _start_time(pid) == started:
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass


def _start_time(pid: int) -> Optional[int]:
    """The start time of process `pid` (clock ticks after boot, /proc/PID/stat), None if gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat[stat.rindex(")") + 2:].split()[19])


def _descendants(pid: int) -> List[Tuple[int, int]]:
    """(pid, start time) of every process below `pid` in the process tree, from /proc."""
    children: Dict[int, List[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = [], list(children.get(pid, []))
    while todo:
        child = todo.pop()
        started = _start_time(child)
        if started is not None:
            found.append((child, started))
        todo.extend(children.get(child, []))
    return found


def master_graph(master_uri: str):
    """A rosgraph Master proxy for queries about topics, services and nodes."""
    import rosgraph

    return rosgraph.Master("/ros_harness", master_uri=master_uri)


class RosCore:
    """A real roscore (rosmaster + rosout) on a free port."""

    def __init__(self, *, port: Optional[int] = None, log_dir: Optional[Path] = None):
        self.port = port or free_port()
        self.log_dir = Path(log_dir or tempfile.mkdtemp(prefix="roscore_"))
        self.uri = f"http://127.0.0.1:{self.port}"
        self.process = ManagedProcess(["roscore", "-p", str(self.port)], name="roscore",
                                      log_path=self.log_dir / "roscore.log", env=self.env())

    def env(self, base: Optional[Mapping[str, str]] = None) -> Dict[str, str]:
        """`base` (default: os.environ) pointed at this master, logs in this core's log dir."""
        env = dict(os.environ if base is None else base)
        env.update(ROS_MASTER_URI=self.uri, ROS_HOSTNAME="127.0.0.1",
                   ROS_LOG_DIR=str(self.log_dir), ROS_HOME=str(self.log_dir))
        env.pop("ROS_IP", None)
        return env

    def start(self, timeout: float = START_TIMEOUT) -> "RosCore":
        self.process.start()
        wait_until(self._ready, timeout, what=f"roscore on port {self.port}",
                   check=self.process.check_alive)
        return self

    def _ready(self) -> bool:
        # The master answers and rosout has registered: nodes can start and log.
        return _lookup_node(master_graph(self.uri), "/rosout")

    def stop(self) -> None:
        self.process.stop()

    def __enter__(self) -> "RosCore":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class RosLaunch:
    """`roslaunch` of a package's launch file, a launch file path, or a single generated node.

    Use `RosLaunch.node(...)` to run one node with private params and remaps, as rosrun would,
    but with roslaunch's process handling.
    """

    def __init__(self, target: Sequence[str], *, master_uri: str, log_dir: Path,
                 args: Optional[Mapping[str, object]] = None,
                 env: Optional[Mapping[str, str]] = None, name: Optional[str] = None):
        self.master_uri = master_uri
        launch_args = [f"{key}:={_launch_value(value)}" for key, value in (args or {}).items()]
        argv = ["roslaunch", "--wait", "--screen", *target, *launch_args]
        self.name = name or " ".join(target)
        log_name = "launch_" + "_".join(Path(t).stem for t in target) + f"_{time.time_ns()}.log"
        self.process = ManagedProcess(argv, name=f"roslaunch {self.name}",
                                      log_path=Path(log_dir) / log_name, env=env)

    @classmethod
    def node(cls, package: str, executable: str, *, master_uri: str, log_dir: Path,
             name: Optional[str] = None, namespace: str = "/",
             params: Optional[Mapping[str, object]] = None,
             remap: Optional[Mapping[str, str]] = None, node_args: str = "",
             env: Optional[Mapping[str, str]] = None) -> "RosLaunch":
        """A launch of one node, written to a temporary launch file in `log_dir`."""
        node_name = name or executable.split(".")[0]
        lines = ["<launch>",
                 f"  <node pkg={quoteattr(package)} type={quoteattr(executable)} "
                 f"name={quoteattr(node_name)} ns={quoteattr(namespace)} "
                 f"args={quoteattr(node_args)} required=\"false\" output=\"screen\">"]
        for key, value in (params or {}).items():
            lines.append(_param_xml(key, value))
        for source, target in (remap or {}).items():
            lines.append(f"    <remap from={quoteattr(source)} to={quoteattr(target)}/>")
        lines += ["  </node>", "</launch>"]
        path = Path(log_dir) / f"node_{node_name}_{time.time_ns()}.launch"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(lines) + "\n")
        return cls([str(path)], master_uri=master_uri, log_dir=log_dir, env=env, name=node_name)

    def start(self) -> "RosLaunch":
        self.process.start()
        return self

    def stop(self, timeout: float = STOP_TIMEOUT) -> Optional[int]:
        return self.process.stop(timeout=timeout)

    def log_tail(self, lines: int = 60) -> str:
        return self.process.log_tail(lines)

    def _graph(self):
        return master_graph(self.master_uri)

    def wait_for_topics(self, topics: Sequence[str], timeout: float = WAIT_TIMEOUT) -> None:
        """Wait until every topic in `topics` has a publisher."""
        def published() -> bool:
            names = {name for name, _ in self._graph().getPublishedTopics("/")}
            return all(topic in names for topic in topics)
        self._wait(published, timeout, f"topics {list(topics)}")

    def wait_for_subscribers(self, topics: Sequence[str], timeout: float = WAIT_TIMEOUT) -> None:
        """Wait until every topic in `topics` has a subscriber."""
        def subscribed() -> bool:
            subscribers = {name for name, nodes in self._graph().getSystemState()[1] if nodes}
            return all(topic in subscribers for topic in topics)
        self._wait(subscribed, timeout, f"subscribers of {list(topics)}")

    def wait_for_services(self, services: Sequence[str], timeout: float = WAIT_TIMEOUT) -> None:
        """Wait until every service in `services` is registered with the master."""
        def registered() -> bool:
            names = {name for name, _ in self._graph().getSystemState()[2]}
            return all(service in names for service in services)
        self._wait(registered, timeout, f"services {list(services)}")

    def wait_for_nodes(self, nodes: Sequence[str], timeout: float = WAIT_TIMEOUT) -> None:
        """Wait until every node in `nodes` is registered with the master."""
        def registered() -> bool:
            graph = self._graph()
            return all(_lookup_node(graph, node) for node in nodes)
        self._wait(registered, timeout, f"nodes {list(nodes)}")

    def node_pid(self, node: str) -> int:
        """The process id of a running node (asked of the node itself over XML-RPC)."""
        import xmlrpc.client

        uri = self._graph().lookupNode(node)
        code, message, pid = xmlrpc.client.ServerProxy(uri).getPid("/ros_harness")
        if code != 1:
            raise HarnessError(f"node {node} did not give its pid: {message}")
        return int(pid)

    def wait_for_exit(self, timeout: float = WAIT_TIMEOUT) -> int:
        """Wait for roslaunch to end by itself (all nodes `required` or finished)."""
        wait_until(lambda: not self.process.alive, timeout, what=f"{self.name} to exit")
        return self.process.popen.returncode

    def _wait(self, condition: Callable[[], bool], timeout: float, what: str) -> None:
        try:
            wait_until(condition, timeout, what=f"{what} from {self.name}",
                       check=self.process.check_alive)
        except TimeoutError as err:
            raise TimeoutError(f"{err}\nlog {self.process.log_path}:\n{self.log_tail()}") from None

    def __enter__(self) -> "RosLaunch":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _lookup_node(graph, node: str) -> bool:
    try:
        return bool(graph.lookupNode(node))
    except Exception:  # noqa: BLE001 - rosgraph raises MasterError for unknown nodes
        return False


def _launch_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _param_xml(key: str, value: object) -> str:
    if isinstance(value, (list, dict)):
        import yaml

        text = yaml.safe_dump(value, default_flow_style=True).strip()
        return f"    <rosparam param={quoteattr(key)} subst_value=\"false\">{_xml_text(text)}</rosparam>"
    if isinstance(value, bool):
        return f"    <param name={quoteattr(key)} type=\"bool\" value=\"{_launch_value(value)}\"/>"
    if isinstance(value, int):
        return f"    <param name={quoteattr(key)} type=\"int\" value=\"{value}\"/>"
    if isinstance(value, float):
        return f"    <param name={quoteattr(key)} type=\"double\" value=\"{value!r}\"/>"
    return f"    <param name={quoteattr(key)} type=\"str\" value={quoteattr(str(value))}/>"


def _xml_text(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _server_command(build: Callable[..., List[str]], **options) -> List[str]:
    """A database server's command line from robot_common.db_servers (the one place it is written)."""
    try:
        return build(**options)
    except (OSError, ValueError) as err:
        raise HarnessError(str(err)) from err


class PouchDBServer:
    """A real CouchDB-compatible HTTP server (pouchdb-server from npm) on a free port.

    With `in_memory=False` (the default) data lives in LevelDB under `data_dir` and survives
    `restart()`, so outage tests can stop and start the same server.
    """

    def __init__(self, data_dir: Path, *, port: Optional[int] = None, in_memory: bool = False):
        self.data_dir = Path(data_dir)
        self.port = port or free_port()
        self.in_memory = in_memory
        self.url = f"http://127.0.0.1:{self.port}"
        self.process: Optional[ManagedProcess] = None

    def start(self, timeout: float = START_TIMEOUT) -> "PouchDBServer":
        argv = _server_command(couchdb_server_command, port=self.port, data_dir=self.data_dir,
                               in_memory=self.in_memory)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.process = ManagedProcess(argv, name=f"pouchdb-server :{self.port}",
                                      log_path=self.data_dir / "server.log",
                                      cwd=self.data_dir).start()
        wait_until(self._ready, timeout, what=f"pouchdb-server on port {self.port}",
                   check=self.process.check_alive)
        return self

    def _ready(self) -> bool:
        with urllib.request.urlopen(self.url + "/", timeout=2) as response:
            return response.status == 200

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop(sig=signal.SIGTERM, timeout=STOP_TIMEOUT)
            wait_until(lambda: not port_open(self.port), WAIT_TIMEOUT, what=f"port {self.port} to close")

    def restart(self) -> "PouchDBServer":
        self.stop()
        return self.start()

    def database_url(self, name: str) -> str:
        return f"{self.url}/{name}"

    def __enter__(self) -> "PouchDBServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class MongoWireServer:
    """A real MongoDB wire-protocol server (nx-27017 from PyPI, on SQLite) on a free port.

    One SQLite file per logical database under `data_dir` (as mongod keeps databases apart);
    its PID file and log live there too, so several servers can run at once. A test and demo
    stand-in for mongod: code under test may only use what real MongoDB offers.
    """

    def __init__(self, data_dir: Path, *, port: Optional[int] = None):
        self.data_dir = Path(data_dir)
        self.port = port or free_port()
        self.url = f"mongodb://127.0.0.1:{self.port}"
        self.process: Optional[ManagedProcess] = None

    def start(self, timeout: float = START_TIMEOUT) -> "MongoWireServer":
        argv = _server_command(mongodb_server_command, port=self.port, data_dir=self.data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.process = ManagedProcess(argv, name=f"nx-27017 :{self.port}",
                                      log_path=self.data_dir / "server.log").start()
        wait_until(lambda: port_open(self.port), timeout, what=f"nx-27017 on port {self.port}",
                   check=self.process.check_alive)
        return self

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop(sig=signal.SIGTERM, timeout=STOP_TIMEOUT)

    def restart(self) -> "MongoWireServer":
        self.stop()
        wait_until(lambda: not port_open(self.port), WAIT_TIMEOUT, what=f"port {self.port} to close")
        return self.start()

    def database_url(self, name: str) -> str:
        return f"{self.url}/{name}"

    def __enter__(self) -> "MongoWireServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def port_open(port: int) -> bool:
    """True when something accepts TCP connections on 127.0.0.1:`port`."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def http_get_json(url: str, timeout: float = 30.0):
    """GET a JSON document (used by tests that look at a CouchDB server directly); credentials in
    the URL (`http://user:pass@host/...`) go as basic authentication, never into an error."""
    import base64
    import json
    from urllib.parse import unquote, urlsplit, urlunsplit

    parts = urlsplit(url)
    headers = {}
    if parts.username:
        pair = f"{unquote(parts.username)}:{unquote(parts.password or '')}"
        headers["Authorization"] = "Basic " + base64.b64encode(pair.encode()).decode()
        netloc = parts.hostname + (f":{parts.port}" if parts.port else "")
        url = urlunsplit(parts._replace(netloc=netloc))
    try:
        request = urllib.request.Request(url, headers=headers)
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return json.loads(response.read().decode())
    except urllib.error.HTTPError as err:
        raise HarnessError(f"GET {url} answered {err.code}: {err.read()[:200]!r}") from err
