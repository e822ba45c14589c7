"""Conversions between GridMap and nav_msgs/OccupancyGrid, and choosing a map from node params."""
import os

import numpy as np
import rospy
from nav_msgs.msg import OccupancyGrid

from robot_sim.building import Building, generate_building
from robot_sim.maps import GridMap, load_map, yaw_to_quaternion


def grid_to_msg(grid: GridMap, frame_id: str = "map", stamp=None) -> OccupancyGrid:
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
    cells = np.asarray(msg.data, dtype=np.int8).reshape(msg.info.height, msg.info.width)
    origin = (msg.info.origin.position.x, msg.info.origin.position.y, 0.0)
    return GridMap(cells, msg.info.resolution, origin, {"source": "OccupancyGrid"})


def building_or_map_from_params():
    """Read `~map_yaml` (a map_server file; empty: generated) and `~seed`.

    Returns (grid, building); `building` is None for a map file (no known areas).
    """
    map_yaml = os.path.expanduser(str(rospy.get_param("~map_yaml", "")))
    if map_yaml:
        return load_map(map_yaml), None
    building: Building = generate_building(int(rospy.get_param("~seed", 0)))
    return building.grid, building
