"""The test_pub_mongodb node of the original's test_launch.launch: sample LaserScans on /scan.

It publishes `--count` sensor_msgs/LaserScan messages (angle_min 0, angle_max 100, angle_increment
20, time_increment 0.5, range_min 10, range_max 20, ranges [10, 10, 20, 20, 10], as the original's
samples) at the original global parameter `data_rate` per second (default 10), once /scan has a
subscriber (at most `--wait` seconds), then exits. The executable nodes/ros_mongo_test_publisher runs
`start` through robot_common.ros_node.run_node.
"""
import argparse
import sys
import threading
import time

import rospy
from sensor_msgs.msg import LaserScan

from robot_common.errors import ConfigError

__all__ = ["sample_scan", "start"]

DEFAULT_DATA_RATE = 10.0


def sample_scan() -> LaserScan:
    """The original's sample LaserScan."""
    return LaserScan(angle_min=0.0, angle_max=100.0, angle_increment=20.0, time_increment=0.5,
                     range_min=10.0, range_max=20.0, ranges=[10.0, 10.0, 20.0, 20.0, 10.0])


def start(argv=None) -> threading.Thread:
    """Read the arguments and `data_rate`, then publish on a thread of its own; the node shuts down
    when done (for robot_common.ros_node.run_node: a bad rate is a ConfigError, exit status 1)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200, help="messages to publish")
    parser.add_argument("--wait", type=float, default=60.0, help="longest wait (s) for a subscriber")
    args = parser.parse_args(rospy.myargv(argv if argv is not None else sys.argv)[1:])
    rate = float(rospy.get_param("data_rate", DEFAULT_DATA_RATE))
    if not rate > 0:
        raise ConfigError(f"data_rate must be positive, got {rate!r}")
    publisher = rospy.Publisher("/scan", LaserScan, queue_size=max(10, args.count))
    thread = threading.Thread(target=_publish, args=(publisher, args.count, rate, args.wait), daemon=True)
    thread.start()
    return thread


def _publish(publisher: rospy.Publisher, count: int, rate: float, wait: float) -> None:
    deadline = time.monotonic() + wait
    while publisher.get_num_connections() == 0 and time.monotonic() < deadline \
            and not rospy.is_shutdown():
        time.sleep(0.05)  # polling the condition "a subscriber is connected"
    rospy.loginfo("Start publishing %d fake LaserScan messages to /scan at %g Hz", count, rate)
    pace = rospy.Rate(rate)
    for _ in range(count):
        if rospy.is_shutdown():
            return
        publisher.publish(sample_scan())
        pace.sleep()
    rospy.loginfo("Complete publishing fake LaserScan messages")
    time.sleep(0.5)  # let the outgoing queue empty before the connection closes
    rospy.signal_shutdown("all messages published")
