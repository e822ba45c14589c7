"""Conversions between `GridMap` and nav_msgs/OccupancyGrid."""
import numpy as np
import rospy
from nav_msgs.msg import OccupancyGrid

from robot_common.maps import GridMap, yaw_to_quaternion

__all__ = ["grid_to_msg", "msg_to_grid"]


def grid_to_msg(grid: GridMap, frame_id: str = "map", stamp=None) -> OccupancyGrid:
    """An OccupancyGrid message of `grid` (stamp: ROS time 0 unless given)."""
    msg = OccupancyGrid()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp if stamp is not None else rospy.Time(0)
    msg.info.map_load_time = msg.header.stamp
    msg.info.resolution = grid.resolution
    msg.info.width, msg.info.height = grid.width, grid.height
    msg.info.origin.position.x, msg.info.origin.position.y = grid.origin[0], grid.origin[1]
    (msg.info.origin.orientation.x, msg.info.origin.orientation.y,
     msg.info.origin.orientation.z, msg.info.origin.orientation.w) = yaw_to_quaternion(grid.origin[2])
    msg.data = grid.cells.ravel().tolist()
    return msg


def msg_to_grid(msg: OccupancyGrid) -> GridMap:
    """The GridMap of an OccupancyGrid message."""
    cells = np.asarray(msg.data, dtype=np.int8).reshape(msg.info.height, msg.info.width)
    origin = (msg.info.origin.position.x, msg.info.origin.position.y, 0.0)
    return GridMap(cells, msg.info.resolution, origin, {"source": "OccupancyGrid"})
