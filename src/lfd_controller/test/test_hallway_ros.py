"""reward_controller's path mode for real (roscore, roslaunch): with a hallway reward it follows
a nav_msgs/Path, stops (zero speed) for what the scan shows inside its safety margin ahead and
says so on /diagnostics; held there while the path is re-planned the same way twice a second
(as move_base does), it reports the path blocked; the goal sent again retries at once."""
import math

import numpy as np
import pytest
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from sensor_msgs.msg import LaserScan

from robot_common.msg import People
from ros_harness import wait_until

pytestmark = pytest.mark.ros


def hallway_reward_file(tmp_path):
    from lfd_controller.hallway_features import HallwayFeatures
    from lfd_controller.learning import save_reward
    from lfd_controller.rewards import LinearReward
    features = HallwayFeatures()
    weights = dict.fromkeys(features.names, 0.0)
    weights.update(path_progress=10.0, speed_squared=-10.0, turn_squared=-1.0, speed_effort=-1.0,
                   turn_effort=-1.0, wall_proximity=-1.0, people_proximity=-5.0)
    return save_reward(LinearReward([weights[n] for n in features.names], features),
                       tmp_path / "hallway_reward.yaml")


class Latest:
    def __init__(self, topic, kind):
        self.msg = None
        self.sub = rospy.Subscriber(topic, kind, self.keep, queue_size=5)

    def keep(self, msg):
        self.msg = msg


def scan_msg(nearest_ahead):
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = rospy.Time.now(), "laser"
    msg.angle_min, msg.angle_increment = -math.pi, 2 * math.pi / 72
    msg.angle_max = msg.angle_min + 71 * msg.angle_increment
    msg.range_min, msg.range_max = 0.05, 8.0
    ranges = np.full(72, 1.2)                  # walls 1.2 m off the laser all round
    ranges[36] = nearest_ahead                 # straight ahead
    msg.ranges = ranges.tolist()
    return msg


def free_map():
    """A 10 x 4 m room round the path, walls on its edges (0.1 m cells, frame odom)."""
    grid = OccupancyGrid()
    grid.header.frame_id = "odom"
    grid.info.resolution, grid.info.width, grid.info.height = 0.1, 100, 40
    grid.info.origin.position.x, grid.info.origin.position.y = -2.0, -2.0
    grid.info.origin.orientation.w = 1.0
    cells = np.zeros((40, 100), np.int8)
    cells[[0, -1], :] = cells[:, [0, -1]] = 100
    grid.data = cells.ravel().tolist()
    return grid


def test_path_mode_follows_the_path_stops_inside_the_safety_margin_and_reports_blocked(
        rospy_node, roslaunch, tmp_path, request):
    launch = roslaunch.node("lfd_controller", "reward_controller",
                            params={"reward_file": str(hallway_reward_file(tmp_path)),
                                    "frame": "odom", "blocked_after": 2.0})
    launch.wait_for_subscribers(["/path", "/scan", "/people", "/odom", "/map", "/goal"],
                                timeout=120)
    publishers = {name: rospy.Publisher(f"/{name}", kind, queue_size=2, latch=True)
                  for name, kind in (("odom", Odometry), ("scan", LaserScan), ("people", People),
                                     ("path", Path), ("map", OccupancyGrid), ("goal", PoseStamped))}
    # latched: left registered, a later test's nodes in this process would get this map and scan
    request.addfinalizer(lambda: [publisher.unregister() for publisher in publishers.values()])
    cmd, diagnostics = Latest("/cmd_vel", Twist), Latest("/diagnostics", DiagnosticArray)
    path = Path()
    path.header.frame_id = "odom"
    for x in np.linspace(0.0, 6.0, 13):
        pose = PoseStamped()
        pose.pose.position.x, pose.pose.orientation.w = x, 1.0
        path.poses.append(pose)
    publishers["path"].publish(path)
    publishers["map"].publish(free_map())      # for the goal below
    publishers["people"].publish(People())
    odom = Odometry()
    odom.pose.pose.orientation.w = 1.0
    ahead = {"range": 4.0}

    replanning = {"on": False}

    def sensors():
        if replanning["on"]:                   # the same way again, as move_base re-plans
            publishers["path"].publish(path)
        odom.header.stamp = rospy.Time.now()
        publishers["odom"].publish(odom)
        publishers["scan"].publish(scan_msg(ahead["range"]))

    def status(level, start):
        sensors()
        item = diagnostics.msg.status[0] if diagnostics.msg is not None else None
        return item is not None and item.level == level and item.message.startswith(start)
    wait_until(lambda: status(DiagnosticStatus.OK, "following") and cmd.msg is not None
               and cmd.msg.linear.x > 0.05, 120, what="driving forward along the path")
    keys = {kv.key: kv.value for kv in diagnostics.msg.status[0].values}
    assert keys["following"] == "the path on /path" and float(keys["length_m"]) == pytest.approx(6.0)
    ahead["range"] = 0.12                      # 0.1 + 0.12 m from the base: inside 0.18 + 0.05
    odom.twist.twist.linear.x = 0.3            # and the robot moving toward it
    wait_until(lambda: status(DiagnosticStatus.WARN, "stopped: scan") and cmd.msg.linear.x == 0.0,
               120, what="a zero speed and the reason")
    replanning["on"] = True                    # held there, re-planned at every poll (<= 0.5 s)
    wait_until(lambda: status(DiagnosticStatus.ERROR, "blocked") and cmd.msg.linear.x == 0.0,
               120, what="the path reported blocked while re-planned the same way")
    # the way clears and no re-plan comes: blocked it stays, until the goal is sent again (once;
    # a re-plan would retry only after the robot stood blocked ~blocked_after s more)
    replanning["on"], ahead["range"], odom.twist.twist.linear.x = False, 4.0, 0.0
    goal = PoseStamped()
    goal.header.frame_id, goal.pose.position.x, goal.pose.orientation.w = "odom", 6.0, 1.0
    publishers["goal"].publish(goal)
    wait_until(lambda: status(DiagnosticStatus.OK, "following") and cmd.msg.linear.x > 0.05,
               120, what="the goal sent again driving the blocked path once more")
    keys = {kv.key: kv.value for kv in diagnostics.msg.status[0].values}
    assert keys["following"] == "a planned path to (6.0, 0.0)"
