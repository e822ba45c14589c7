"""The demo recorder for real (roscore, the node through roslaunch): what it saw just before
~start opens the bag. A simulator publishes a step's scan after its odometry, so the scan, the
people and the clock of the step a recording starts from reach the recorder before ~start; the
recorder keeps the newest few of each (topics arrive in any order: here a newer one follows) and
writes them first."""
import xmlrpc.client

import pytest
import rosbag
import rospy
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan, TimeReference
from std_msgs.msg import String
from std_srvs.srv import Trigger

from robot_common.msg import People, Person
from ros_harness import wait_for_subscriber, wait_until

pytestmark = pytest.mark.ros

NS = "/start_buffer"                 # its own topics: no publisher of another test reaches it
RECORDER = f"{NS}/demo_recorder"
STEPS = 6                            # steps recorded after ~start (the recorder needs 5)
CALLER = "/recording_start_test"
T0 = 12.5                            # the simulator's clock at step 0 (s)


class Recorder:
    """How many messages the recorder node has read on each topic (its XML-RPC getBusStats)."""

    def __init__(self):
        code, message, uri = rospy.get_master().lookupNode(RECORDER)
        assert code == 1, message
        self.node = xmlrpc.client.ServerProxy(uri)

    def read(self) -> dict:
        """topic -> messages read so far."""
        code, message, (_, subscribed, _) = self.node.getBusStats(CALLER)
        assert code == 1, message
        # rospy's subscriber statistics: (connection id, bytes, messages, drop estimate, connected)
        return {name: sum(link[2] for link in links) for name, links in subscribed}

    def wait_read(self, counts: dict) -> None:
        """Wait until the recorder has read at least `counts` (topic -> messages)."""
        wait_until(lambda: all(self.read().get(topic, 0) >= count for topic, count in counts.items()),
                   60, what=f"the recorder to read {counts}")

    def handled(self, publisher, message, then) -> None:
        """Publish `message` and make sure the recorder's callback has run on it: rospy reads a
        connection's next message only after the callbacks of the one before have returned, so
        once `then` (published after `message` was read) has been read, `message` was handled."""
        topic = publisher.resolved_name
        before = self.read().get(topic, 0)
        publisher.publish(message)
        self.wait_read({topic: before + 1})
        publisher.publish(then)
        self.wait_read({topic: before + 2})


def scan_msg(stamp, ranges):
    scan = LaserScan()
    scan.header.stamp, scan.header.frame_id = stamp, "laser"
    scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max = -1.5, 1.0, 0.05, 8.0
    scan.ranges = ranges
    return scan


def people_msg(stamp, name, x, y):
    people = People()
    people.header.stamp, people.header.frame_id = stamp, "odom"
    person = Person(name=name)
    person.position.x, person.position.y = x, y
    people.people.append(person)
    return people


def clock_msg(stamp, t):
    clock = TimeReference()
    clock.header.stamp, clock.time_ref = stamp, rospy.Time.from_sec(t)
    return clock


def step_msgs(stamp, k):
    """Step k's odometry and applied command (the robot drives along x at 0.2 m/s)."""
    odom = Odometry()
    odom.header.stamp = stamp
    odom.pose.pose.position.x, odom.pose.pose.orientation.w = 0.02 * k, 1.0
    odom.twist.twist.linear.x = 0.2
    applied = TwistStamped()
    applied.header.stamp, applied.twist.linear.x = stamp, 0.2
    return odom, applied


def test_the_scan_people_and_clock_seen_just_before_start_open_the_bag(rospy_node, roslaunch,
                                                                     tmp_path):
    from robot_sim.scenarios import load_scenario

    launch = roslaunch.node("lfd_controller", "demo_recorder", namespace=NS,
                            params={"bag_dir": str(tmp_path / "bags"), "use_applied_cmd": True})
    launch.wait_for_services([f"{RECORDER}/start", f"{RECORDER}/stop"])
    kinds = {"scan": LaserScan, "people": People, "sim_time": TimeReference, "odom": Odometry,
             "cmd_vel_applied": TwistStamped}
    out = {name: rospy.Publisher(f"{NS}/{name}", kind, queue_size=50) for name, kind in kinds.items()}
    out["scenario"] = rospy.Publisher(f"{NS}/scenario", String, queue_size=1, latch=True)
    for publisher in out.values():
        wait_for_subscriber(publisher, RECORDER, 60)
    out["scenario"].publish(String(data=load_scenario("static_obstacle").to_yaml()))
    recorder = Recorder()

    # before ~start: step 0 (odometry, command, clock) and the scan and people seen at it, each
    # followed by a newer message (other content) that proves the recorder has handled it
    base = rospy.Time.now()
    stamps = [base + rospy.Duration.from_sec(0.1 * k) for k in range(STEPS + 2)]
    later = base + rospy.Duration.from_sec(0.05)
    scan, people, clock = (scan_msg(base, [1.0, 1.5, 2.25, 4.0]), people_msg(base, "p0", 1.2, -0.4),
                           clock_msg(base, T0))
    odom, applied = step_msgs(base, 0)
    out["odom"].publish(odom)
    out["cmd_vel_applied"].publish(applied)
    recorder.handled(out["scan"], scan, scan_msg(later, [7.0] * 4))
    recorder.handled(out["people"], people, people_msg(later, "p1", -3.0, 3.0))
    recorder.handled(out["sim_time"], clock, clock_msg(later, T0 + 0.05))

    start = rospy.ServiceProxy(f"{RECORDER}/start", Trigger)
    wait_until(lambda: start().success, 60, what="the recorder to have the scenario and start")
    for k in range(1, STEPS + 2):
        odom, applied = step_msgs(stamps[k], k)
        out["odom"].publish(odom)
        out["cmd_vel_applied"].publish(applied)
        out["sim_time"].publish(clock_msg(stamps[k], T0 + 0.1 * k))
    # steps 0..STEPS + 1 read (and the second clock before ~start): steps 1..STEPS handled
    recorder.wait_read({f"{NS}/odom": STEPS + 2, f"{NS}/cmd_vel_applied": STEPS + 2,
                        f"{NS}/sim_time": STEPS + 3})
    answer = rospy.ServiceProxy(f"{RECORDER}/stop", Trigger)()
    assert answer.success, answer.message

    bag_file = next((tmp_path / "bags").glob("*.bag"))
    with rosbag.Bag(str(bag_file)) as bag:
        first = [(topic, msg) for topic, msg, when in bag.read_messages() if when <= base]
    scans = [m for topic, m in first if topic == "/scan"]
    assert [(list(m.ranges), m.angle_min, m.header.frame_id) for m in scans] == \
        [([1.0, 1.5, 2.25, 4.0], -1.5, "laser")], first
    seen = [(p.name, p.position.x, p.position.y) for topic, m in first if topic == "/people"
            for p in m.people]
    assert seen == [("p0", 1.2, -0.4)], first
    clocks = [m.time_ref.to_sec() for topic, m in first if topic == "/sim_time"]
    assert clocks == [T0], first
