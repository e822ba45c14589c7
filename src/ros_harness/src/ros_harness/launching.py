"""Launch bookkeeping shared by the tests (the `roslaunch` fixture) and the demo.

A `LaunchSet` starts roslaunch targets and single nodes against one roscore, remembers them, and
`stop_all()` stops every one (by process id, newest first) and then deletes the parameters they
set on the master: the master may outlive the set (a test session, the demo's chapters), and a
node started later under the same name must not read stale private parameters.

    launches = LaunchSet(core, log_dir)
    sim = launches("robot_sim", "sim.launch", seed=1)      # or launches("/path/to/file.launch")
    node = launches.node("robot_sim", "sensor_sim", params={"image_rate": 10.0})
    launches.stop(node)                                     # one launch, now
    launches.stop_all()
"""
import xmlrpc.client
from pathlib import Path
from typing import List, Set

from ros_harness.errors import HarnessError
from ros_harness.processes import RosCore, RosLaunch

__all__ = ["LaunchSet"]

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
        """Stop every launch (newest first), then delete the parameters set since the set began."""
        for launch in reversed(self.launched):
            launch.stop()
        self.launched.clear()
        master = xmlrpc.client.ServerProxy(self.core.uri)
        for name in set(_param_names(self.core.uri)) - self.params_before:
            master.deleteParam(_CALLER_ID, name)


def _param_names(master_uri: str) -> List[str]:
    code, message, names = xmlrpc.client.ServerProxy(master_uri).getParamNames(_CALLER_ID)
    if code != 1:
        raise HarnessError(f"cannot list parameters of {master_uri}: {message}")
    return names
