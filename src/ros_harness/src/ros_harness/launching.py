"""Launch bookkeeping shared by the tests (the `roslaunch` fixture) and the demo.

A `LaunchSet` starts roslaunch targets and single nodes against one roscore, remembers them, and
`stop_all()` stops every one (by process id, newest first) and then deletes the parameters they
set on the master: the master may outlive the set (a test session, the demo's chapters), and a
node started later under the same name must not read stale private parameters. It also forgets
the registrations of nodes that died without unregistering (killed after the stop timeout), as
`rosnode cleanup` does: a later node would be told to connect to them.

    launches = LaunchSet(core, log_dir)
    sim = launches("robot_sim", "sim.launch", seed=1)      # or launches("/path/to/file.launch")
    node = launches.node("robot_sim", "sensor_sim", params={"image_rate": 10.0})
    launches.stop(node)                                     # one launch, now
    launches.stop_all()
"""
import socket
import xmlrpc.client
from pathlib import Path
from typing import Dict, List, Set
from urllib.parse import urlsplit

from ros_harness.errors import HarnessError
from ros_harness.processes import RosCore, RosLaunch

__all__ = ["LaunchSet", "forget_dead_nodes", "refuses_connections"]

_CALLER_ID = "/ros_harness_launches"


class LaunchSet:
    """The launches started against one roscore, stopped together (see the module docstring)."""

    def __init__(self, core: RosCore, log_dir: Path):
        self.core = core
        self.log_dir = Path(log_dir)
        self.launched: List[RosLaunch] = []
        self.params_before: Set[str] = set(_param_names(core.uri))

    def __call__(self, package_or_path: str, launch_file: str = "", **args) -> RosLaunch:
        """Start `roslaunch package launch_file` (or a launch file path) with `args` (name:=value)."""
        target = [package_or_path, launch_file] if launch_file else [package_or_path]
        return self.add(RosLaunch(target, master_uri=self.core.uri, log_dir=self.log_dir, args=args,
                                  env=self.core.env()))

    def node(self, package: str, executable: str, **options) -> RosLaunch:
        """Start one node (see `RosLaunch.node` for the options: name, params, remap, ...)."""
        return self.add(RosLaunch.node(package, executable, master_uri=self.core.uri,
                                       log_dir=self.log_dir, env=self.core.env(), **options))

    def add(self, launch: RosLaunch) -> RosLaunch:
        """Start `launch` (not yet started) and remember it."""
        self.launched.append(launch)
        return launch.start()

    def stop(self, launch: RosLaunch) -> None:
        """Stop one launch of the set now; the others keep running."""
        launch.stop()
        self.launched.remove(launch)

    def stop_all(self) -> None:
        """Stop every launch (newest first), then delete the parameters set since the set began
        and forget the registrations of nodes that are gone (`forget_dead_nodes`)."""
        for launch in reversed(self.launched):
            launch.stop()
        self.launched.clear()
        master = xmlrpc.client.ServerProxy(self.core.uri)
        for name in set(_param_names(self.core.uri)) - self.params_before:
            master.deleteParam(_CALLER_ID, name)
        forget_dead_nodes(self.core.uri)


def forget_dead_nodes(master_uri: str) -> List[str]:
    """Unregister every topic and service of the nodes whose API no longer accepts connections
    (killed, so never unregistered); the names of those nodes. A node that answers, even slowly,
    is left alone."""
    master = xmlrpc.client.ServerProxy(master_uri)
    code, message, (publishers, subscribers, services) = master.getSystemState(_CALLER_ID)
    if code != 1:
        raise HarnessError(f"cannot read the system state of {master_uri}: {message}")
    dead: Dict[str, str] = {}
    for node in sorted({node for _, nodes in publishers + subscribers + services for node in nodes}):
        code, _, uri = master.lookupNode(_CALLER_ID, node)
        if code == 1 and refuses_connections(uri):
            dead[node] = uri
    for topic, nodes in publishers:
        for node in set(nodes) & set(dead):
            master.unregisterPublisher(node, topic, dead[node])
    for topic, nodes in subscribers:
        for node in set(nodes) & set(dead):
            master.unregisterSubscriber(node, topic, dead[node])
    for service, nodes in services:
        for node in set(nodes) & set(dead):
            code, _, service_uri = master.lookupService(_CALLER_ID, service)
            if code == 1:
                master.unregisterService(node, service, service_uri)
    return sorted(dead)


def refuses_connections(uri: str) -> bool:
    """Whether the host and port of `uri` refuse a TCP connection (nothing listens there)."""
    address = urlsplit(uri)
    try:
        socket.create_connection((address.hostname, address.port), timeout=5.0).close()
    except ConnectionRefusedError:
        return True
    except OSError:       # slow or unreachable, not known to be gone
        return False
    return False


def _param_names(master_uri: str) -> List[str]:
    code, message, names = xmlrpc.client.ServerProxy(master_uri).getParamNames(_CALLER_ID)
    if code != 1:
        raise HarnessError(f"cannot list parameters of {master_uri}: {message}")
    return names
