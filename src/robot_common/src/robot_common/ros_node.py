"""The one ROS-node helper layer of the workspace: parameters, logging on rosout, ROS_HOME,
and the start-up / exit convention of every node executable.

    def main() -> int:
        return run_node("traffic_gp", start, loggers=("traffic_gp",))

`start()` reads its `NodeConfig` with `read_config`, builds the core and wires ROS; a
`ConfigError` (or another error the node names in `fatal`) becomes one FATAL line on rosout, one
`ERROR: ...` line on stderr and exit status 1; otherwise the node spins until shutdown.
"""
import logging
import math
import sys
from typing import Callable, Iterable, Optional, Sequence, Tuple, Type, TypeVar, Union

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path

from robot_common.errors import ConfigError
from robot_common.maps import quaternion_to_yaw, yaw_to_quaternion
from robot_common.params import NodeConfig
from robot_common.paths import ros_home

__all__ = ["route_logging", "read_config", "ros_home", "run_node", "odom_state", "pose_2d",
           "path_msg"]

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


def path_msg(points, frame_id: str, stamp: Optional[rospy.Time] = None, *,
             headings: Union[None, str, Sequence[float]] = None,
             stamps: Optional[Sequence[rospy.Time]] = None) -> Path:
    """A nav_msgs/Path through `points` ((x, y) each; none gives a Path without poses).

    Args:
        points: (N, 2) positions in `frame_id`.
        frame_id: the frame of the path and of every pose.
        stamp: the path's stamp (None: zero, "unstamped").
        headings: each pose's yaw: None for none (the identity rotation), "along" for the
            direction from the point before to the point after (at the ends: to the next / from
            the one before; a lone point: yaw 0), or N yaws (rad).
        stamps: each pose's stamp (N of them); None: the path's stamp.

    Raises:
        ValueError: `points` is not (N, 2), or `headings` / `stamps` do not give N values.
    """
    xy = np.asarray(points, dtype=float)
    if xy.size == 0:
        xy = xy.reshape(0, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"path points must be (N, 2) (x, y) pairs, got shape {xy.shape}")
    yaws = _path_headings(xy, headings)
    if stamps is not None and len(stamps) != len(xy):
        raise ValueError(f"{len(stamps)} pose stamps for {len(xy)} path points")
    msg = Path()
    msg.header.frame_id = frame_id
    msg.header.stamp = rospy.Time() if stamp is None else stamp
    for i, (x, y) in enumerate(xy):
        pose = PoseStamped()
        pose.header.frame_id = frame_id
        pose.header.stamp = msg.header.stamp if stamps is None else stamps[i]
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        q = pose.pose.orientation
        if yaws is None:
            q.w = 1.0
        else:
            q.x, q.y, q.z, q.w = yaw_to_quaternion(yaws[i])
        msg.poses.append(pose)
    return msg


def _path_headings(xy: np.ndarray, headings) -> Optional[Sequence[float]]:
    """The yaws `path_msg`'s `headings` asks for (None: no rotation)."""
    if headings is None:
        return None
    if isinstance(headings, str):
        if headings != "along":
            raise ValueError(f"headings must be None, 'along' or one yaw per point, got {headings!r}")
        last = len(xy) - 1
        ahead = [xy[min(i + 1, last)] - xy[max(i - 1, 0)] for i in range(len(xy))]
        return [math.atan2(dy, dx) for dx, dy in ahead]
    yaws = [float(yaw) for yaw in headings]
    if len(yaws) != len(xy):
        raise ValueError(f"{len(yaws)} headings for {len(xy)} path points")
    return yaws
