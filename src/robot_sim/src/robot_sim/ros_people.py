"""ROS side of the people simulator: simulated robots publish PeopleCount messages with known
truth (robot_sim.people), stamped in simulated time."""
import os
from typing import Optional

import rospy
from geometry_msgs.msg import Point
from nav_msgs.msg import OccupancyGrid

from robot_common.maps import GridMap, load_map
from robot_common.msg import PeopleCount
from robot_common.ros_maps import msg_to_grid
from robot_common.ros_node import read_config
from robot_sim.building import building_or_map
from robot_sim.params import PeopleSimParams
from robot_sim.people import PeopleSimulator, View

__all__ = ["MONDAY_EPOCH", "sim_stamp", "map_from_topic", "PeopleSimNode", "start"]

MONDAY_EPOCH = 1704067200.0   # Monday 2024-01-01 00:00 UTC


def sim_stamp(hours: float, utc_offset_hours: float) -> rospy.Time:
    """The ROS time of `hours` since Monday 00:00 of the simulated week (in the given zone)."""
    return rospy.Time.from_sec(MONDAY_EPOCH + (hours - utc_offset_hours) * 3600.0)


def map_from_topic(timeout: float = 120.0) -> GridMap:
    """The first map on the `map` topic (rospy.ROSException after `timeout` seconds)."""
    return msg_to_grid(rospy.wait_for_message("map", OccupancyGrid, timeout=timeout))


class PeopleSimNode:
    """Simulated robots counting people in the halls, at random places, in simulated time.

    Parameters (private; robot_sim.params.PeopleSimParams, defaults in config/people_sim.yaml):
    map_yaml ("": the generated building of `seed` and `layout` ("hall" or "loop"), as
    robot_sim's map_publisher makes it; else halls derived from the map),
    use_map_topic (false; true: halls derived from the first `map` message, nav_msgs/OccupancyGrid),
    seed (0), sim_seed (1: places, times, counts), cell_size (0.5 m), robots (3), rate
    (5 views per wall-clock second, all robots), time_scale (60 simulated seconds per second),
    start_hour (10.0 = Monday 10:00), utc_offset_hours (0; stamps are simulated times in this
    zone), radius (4 m view), duration (0 s: snapshots), total_counts (false: per-cell counts;
    true: one total within `radius`), frame_id ("map").
    Topics: publishes `people_counts` (robot_common/PeopleCount).

    `grid`: the map when use_map_topic is set and map_yaml empty (the node passes
    `map_from_topic()`). Construction builds the simulator (MapError for an unreadable map file);
    `setup()` creates the publisher and the timer.
    """

    def __init__(self, config: PeopleSimParams, *, grid: Optional[GridMap] = None):
        self.config = config
        options = dict(seed=config.sim_seed)
        if config.map_yaml or grid is not None:
            if config.map_yaml:
                grid = load_map(os.path.expanduser(config.map_yaml))
            self.sim = PeopleSimulator.from_map(grid, config.cell_size, **options)
        else:
            _, building = building_or_map("", config.seed, config.layout)
            self.sim = PeopleSimulator.from_building(building, config.cell_size, **options)
        self.count = 0

    def setup(self) -> None:
        self.publisher = rospy.Publisher("people_counts", PeopleCount, queue_size=100)
        self.start_wall = rospy.get_time()
        rospy.Timer(rospy.Duration(1.0 / self.config.rate), lambda _: self.tick())

    def sim_hours(self) -> float:
        elapsed = rospy.get_time() - self.start_wall
        return self.config.start_hour + elapsed * self.config.time_scale / 3600.0

    def tick(self) -> None:
        c = self.config
        view = self.sim.observe(1, start=self.sim_hours(), hours=1e-9, radius=c.radius,
                                duration=c.duration)[0]
        view.robot_id = f"robot_{self.count % c.robots}"
        self.count += 1
        self.publisher.publish(self.to_msg(view))

    def to_msg(self, view: View) -> PeopleCount:
        c, cells = self.config, self.sim.cells
        msg = PeopleCount()
        msg.header.stamp = sim_stamp(view.t, c.utc_offset_hours)
        msg.header.frame_id = c.frame_id
        msg.robot_id = view.robot_id
        msg.robot_position = Point(view.x, view.y, 0.0)
        msg.duration = view.duration
        msg.radius = c.radius
        if c.total_counts:
            msg.total_count = int(view.counts.sum())
        else:
            msg.cells = [Point(cells.x[i], cells.y[i], 0.0) for i in view.cells]
            msg.seen_fraction = view.fractions.tolist()
            msg.counts = view.counts.astype(int).tolist()
        return msg


def start() -> PeopleSimNode:
    """The node's start-up: read its parameters, build it, wire ROS."""
    config = read_config(PeopleSimParams)
    grid = map_from_topic() if config.use_map_topic and not config.map_yaml else None
    node = PeopleSimNode(config, grid=grid)
    node.setup()
    return node
