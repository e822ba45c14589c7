"""The people counter through roslaunch, against robot_sim's simulated robot: its laser (walls and
people), tf map -> odom -> base_link -> laser and a people tracker with 10% misses and 10% false
tracks, checked against the simulator's true people (traffic_gp.sim.counting_check)."""
import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_sim import generate_building
from ros_harness import wait_until
from traffic_gp.sim.counting_check import TrueScan, check_counts

pytestmark = pytest.mark.ros


class Watch:
    """A PeopleCount message as the check reads it."""

    def __init__(self, msg, cells):
        self.start, self.duration = msg.header.stamp.to_sec(), msg.duration
        self.cells = cells.index_at(np.array([p.x for p in msg.cells]),
                                    np.array([p.y for p in msg.cells]))
        self.counts = np.asarray(msg.counts)


def test_the_counter_counts_the_simulated_crowd_as_it_truly_was(roslaunch, rospy_node):
    import rospy
    import tf2_ros
    from sensor_msgs.msg import LaserScan
    from std_srvs.srv import Trigger

    from robot_common.maps import quaternion_to_yaw
    from robot_common.msg import People, PeopleCount

    buffer = tf2_ros.Buffer(cache_time=rospy.Duration(600))
    listener = tf2_ros.TransformListener(buffer)
    scans, truth, counts = [], {}, []
    subscribers = [
        rospy.Subscriber("/scan", LaserScan, scans.append, queue_size=100),
        rospy.Subscriber("/sensor_sim/people_truth", People,
                         lambda msg: truth.__setitem__(msg.header.stamp.to_sec(), msg), queue_size=100),
        rospy.Subscriber("/people_counts", PeopleCount, counts.append, queue_size=100)]
    try:
        # a busy Wednesday afternoon (peak density 1 person/m^2 in the main hall), 5 s watches
        roslaunch("robot_sim", "sim.launch", crowd=True, crowd_hour=62.0, peak_density=1.0)
        counter = roslaunch("traffic_gp", "people_counter.launch", watch=5.0, robot_id="robot_7")
        wait_until(lambda: len(counts) >= 9, 300, what="9 watches of counts",
                   check=lambda: counter.process.check_alive())
    finally:
        for subscriber in subscribers:
            subscriber.unregister()
        listener.unregister()
    status = rospy.ServiceProxy("/people_counter/status", Trigger)().message
    assert "robot robot_7" in status and "scans used" in status, status
    assert {msg.robot_id for msg in counts} == {"robot_7"}
    assert {msg.header.frame_id for msg in counts} == {"map"}

    cells = CellGrid.from_map(generate_building(0).grid, 0.5)
    true_scans = []
    for scan in scans:
        stamp = scan.header.stamp
        if stamp.to_sec() not in truth or not buffer.can_transform("map", "laser", stamp):
            continue
        pose = buffer.lookup_transform("map", "laser", stamp).transform
        yaw = quaternion_to_yaw(pose.rotation.x, pose.rotation.y, pose.rotation.z, pose.rotation.w)
        people = [(p.name, p.position.x, p.position.y) for p in truth[stamp.to_sec()].people]
        true_scans.append(TrueScan(stamp.to_sec(), (pose.translation.x, pose.translation.y, yaw),
                                   scan.angle_min, scan.angle_increment,
                                   np.asarray(scan.ranges, dtype=float), people))
    # the first watch may have begun before this test listened: leave it out
    result = check_counts(cells, [Watch(msg, cells) for msg in counts[1:]], true_scans,
                          max_range=8.0)
    print(result.line())
    assert result.truth >= 50, result.line()
    assert 0.9 <= result.count_ratio <= 1.1, result.line()
    assert result.recall >= 0.95, result.line()
    assert result.hidden_reported == 0, result.line()
