"""Every node that takes a database URL warns once at start when the URL carries a password
(roslaunch prints the start of every parameter value), in its log, quoting the URL redacted.
ros_mongo's own nodes are tested in src/ros_mongo/test/test_credentials_warning.py, igmm_layers'
in its package; these are the crowd model's ~central_url and the demonstration recorder's
~db_url, each through roslaunch. The URLs point at a closed port: the warning must come at start,
before the node ever connects."""
from pathlib import Path

import pytest

from ros_harness import free_port, wait_until

pytestmark = pytest.mark.ros

SECRET = "s3cr3t-pass"


def _url() -> str:
    return f"http://robot:{SECRET}@127.0.0.1:{free_port()}/fleet"


def _map(tmp_path) -> str:
    from robot_common.maps import save_map
    from robot_sim import generate_building

    return str(save_map(generate_building(0).grid, tmp_path / "map.yaml"))


# node: package, launch file, node name, a service it offers once started, launch arguments
NODES = {
    "traffic_gp": ("traffic_gp", "traffic_gp.launch", "/traffic_gp", "/traffic_gp/status",
                   lambda url, tmp: dict(central_url=url, source="topic", map_yaml=_map(tmp))),
    "demo_recorder": ("lfd_controller", "teleop_record.launch", "/demo_recorder",
                      "/demo_recorder/start", lambda url, tmp: dict(db_url=url, source="person_like")),
}


def _warnings(roscore, name):
    """The warning lines in the node's own log file (rospy writes every line there; /rosout
    misses lines logged before the node's /rosout connection is up)."""
    lines = []
    for path in Path(roscore.log_dir).rglob(f"{name.strip('/')}-*.log"):
        lines += [line for line in path.read_text(errors="replace").splitlines()
                  if "carries a password" in line]
    return lines


@pytest.mark.parametrize("node", sorted(NODES))
def test_the_node_warns_once_at_start_without_showing_the_password(node, roslaunch, roscore,
                                                                   rospy_node, tmp_path):
    from rosgraph_msgs.msg import Log

    package, launch_file, name, service, args = NODES[node]
    logs = []
    rosout = rospy_node.Subscriber("/rosout_agg", Log, logs.append)
    try:
        launch = roslaunch(package, launch_file, **args(_url(), tmp_path))
        warned = wait_until(lambda: _warnings(roscore, name), 120,
                            what=f"{node}'s password warning in its log file")
        assert "[WARNING]" in warned[0] and "robot:***@" in warned[0]
        # once the node is up (its start-up done), the warning was still said once
        launch.wait_for_services([service], timeout=120)
        assert launch.process.alive
        assert len(_warnings(roscore, name)) == 1
        assert all(SECRET[:4] not in m.msg for m in logs)
        for path in Path(roscore.log_dir).rglob(f"{name.strip('/')}-*.log"):
            assert SECRET[:4] not in path.read_text(errors="replace")
    finally:
        rosout.unregister()
