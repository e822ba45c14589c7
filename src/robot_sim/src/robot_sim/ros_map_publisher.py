"""ROS side of the map publisher: a map published as map_server does (Debian ships no map_server)."""
from pathlib import Path

import rospy
from nav_msgs.msg import MapMetaData, OccupancyGrid

from robot_common.ros_maps import grid_to_msg
from robot_common.ros_node import read_config
from robot_sim.building import building_or_map
from robot_sim.params import MapPublisherParams

__all__ = ["MapPublisher", "start"]


class MapPublisher:
    """Publishes a map file or a generated building floor, latched, once.

    Parameters (robot_sim.params.MapPublisherParams): ~map_yaml (""; empty: the generated
    building of ~seed), ~seed (0), ~layout ("hall"; "loop": the floor with west and north
    corridors), ~frame_id ("map"), ~labels_path ("": if set, the generated
    building's labels are written there in the map_labelling JSON format).
    Topics (out, latched): map (nav_msgs/OccupancyGrid), map_metadata (nav_msgs/MapMetaData).

    Construction reads the map (robot_common MapError when the file cannot be read); `setup()`
    writes the labels file and publishes.
    """

    def __init__(self, config: MapPublisherParams):
        self.config = config
        self.grid, self.building = building_or_map(config.map_yaml, config.seed,
                                                     config.layout)

    def setup(self) -> None:
        labels_path = self.config.labels_path
        if labels_path and self.building is not None:
            Path(labels_path).parent.mkdir(parents=True, exist_ok=True)
            Path(labels_path).write_text(self.building.labels_json())
        msg = grid_to_msg(self.grid, self.config.frame_id, rospy.Time.now())
        self._metadata = rospy.Publisher("map_metadata", MapMetaData, queue_size=1, latch=True)
        self._map = rospy.Publisher("map", OccupancyGrid, queue_size=1, latch=True)
        self._metadata.publish(msg.info)
        self._map.publish(msg)
        grid = self.grid
        rospy.loginfo(f"map_publisher: {grid.width}x{grid.height} cells at {grid.resolution} m "
                      f"from {grid.meta.get('source')}")


def start() -> MapPublisher:
    """The node's start-up: read its parameters, build it, wire ROS."""
    publisher = MapPublisher(read_config(MapPublisherParams))
    publisher.setup()
    return publisher
