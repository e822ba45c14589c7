"""The one ROS-node helper layer of the workspace: parameters, logging on rosout, ROS_HOME,
and the start-up / exit convention of every node executable.

    def main() -> int:
        return run_node("traffic_gp", start, loggers=("traffic_gp",))

`start()` reads its `NodeConfig` with `read_config`, builds the core and wires ROS; a
`ConfigError` (or another error the node names in `fatal`) becomes one FATAL line on rosout, one
`ERROR: ...` line on stderr and exit status 1; otherwise the node spins until shutdown.
"""
import logging
import sys
from typing import Callable, Iterable, Tuple, Type, TypeVar

import rospy

from robot_common.errors import ConfigError
from robot_common.maps import quaternion_to_yaw
from robot_common.params import NodeConfig
from robot_common.paths import ros_home

__all__ = ["route_logging", "read_config", "ros_home", "run_node", "odom_state", "pose_2d"]

ConfigT = TypeVar("ConfigT", bound=NodeConfig)


class _RospyHandler(logging.Handler):
    """A pure-Python core's `logging` records, sent to rosout at the same level."""

    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        if record.levelno >= logging.ERROR:
            rospy.logerr(text)
        elif record.levelno >= logging.WARNING:
            rospy.logwarn(text)
        elif record.levelno >= logging.INFO:
            rospy.loginfo(text)
        else:
            rospy.logdebug(text)


def route_logging(*logger_names: str) -> None:
    """Send the log records of the named cores' loggers to rosout (once per logger)."""
    for name in logger_names:
        logger = logging.getLogger(name)
        if not any(isinstance(h, _RospyHandler) for h in logger.handlers):
            logger.addHandler(_RospyHandler())
            logger.setLevel(logging.INFO)
            logger.propagate = False


def read_config(config_cls: Type[ConfigT], namespace: str = "~") -> ConfigT:
    """The node's parameters under `namespace` (its private ones by default), checked."""
    params = rospy.get_param(namespace, {}) if rospy.has_param(namespace) else {}
    return config_cls.from_mapping(params)


def run_node(node_name: str, start: Callable[[], object], *, loggers: Iterable[str] = (),
             fatal: Tuple[Type[BaseException], ...] = (), anonymous: bool = False) -> int:
    """Initialise the node, run `start()`, spin; the exit status of the node executable."""
    rospy.init_node(node_name, anonymous=anonymous)
    route_logging(*loggers)
    try:
        start()
    except (ConfigError,) + tuple(fatal) as err:
        rospy.logfatal(f"{rospy.get_name()}: {err}")
        print(f"ERROR: {rospy.get_name()}: {err}", file=sys.stderr)
        return 1
    rospy.spin()
    return 0


def shut_down_rospy(reason: str) -> None:
    """`rospy.signal_shutdown(reason)` for a process that goes on afterwards (a test worker, the
    demo while it stops its launches). rospy's shutdown closes its XML-RPC server's socket but
    leaves the server's `serve_forever` polling the closed socket: that thread then keeps a core
    busy until the process exits. Asking `serve_forever` to return as well ends the thread."""
    servers = [getattr(hook, "__self__", None) for hook in rospy.core._shutdown_hooks]
    servers = [node.server for node in servers if getattr(node, "server", None) is not None]
    rospy.signal_shutdown(reason)
    for server in servers:
        # what BaseServer.shutdown() sets, without its wait: the loop returns on its next poll
        server._BaseServer__shutdown_request = True


def odom_state(msg) -> list:
    """(px, py, yaw, v, w) from a nav_msgs/Odometry."""
    pose, twist = msg.pose.pose, msg.twist.twist
    q = pose.orientation
    return [pose.position.x, pose.position.y, quaternion_to_yaw(q.x, q.y, q.z, q.w),
            twist.linear.x, twist.angular.z]


def pose_2d(transform) -> Tuple[float, float, float]:
    """(x, y, yaw) of a geometry_msgs/TransformStamped (a tf lookup), in the plane."""
    t, r = transform.transform.translation, transform.transform.rotation
    return t.x, t.y, quaternion_to_yaw(r.x, r.y, r.z, r.w)
