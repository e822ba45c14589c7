"""The workspace's shared vocabulary (no ROS): maps and map files, cells and time of week,
the unicycle model, navigation-task geometry, paths as polylines (`robot_common.polylines`),
errors and the node-parameter convention.

`robot_common.paths.ros_home` resolves $ROS_HOME. The ROS-side helpers live in
`robot_common.ros_node` and `robot_common.ros_maps` (they import rospy)."""
from robot_common.cells import DWELL_TIME_S, HOURS_PER_WEEK, CellGrid, View, exposure, hours_of_week
from robot_common.errors import (
                                 CommonError,
                                 ConfigError,
                                 MapError,
                                 ModelError,
                                 NotFittedError,
                                 TaskError,
                                 WorkspaceError,
)
from robot_common.maps import FREE, OCCUPIED, UNKNOWN, GridMap, load_map, raycast, save_map
from robot_common.params import NodeConfig, param

__all__ = [
    "DWELL_TIME_S", "HOURS_PER_WEEK", "CellGrid", "View", "exposure", "hours_of_week",
    "CommonError", "ConfigError", "MapError", "ModelError", "NotFittedError", "TaskError",
    "WorkspaceError",
    "FREE", "OCCUPIED", "UNKNOWN", "GridMap", "load_map", "raycast", "save_map",
    "NodeConfig", "param",
]
