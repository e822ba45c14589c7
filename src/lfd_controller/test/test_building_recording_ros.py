"""Recording a drive in a building for real (roscore, roslaunch): the demo recorder keeps the
path, the scan and the tracked people beside the steps, and learn_reward --kind hallway learns a
path-mode reward from the bag, checked with the controller on the recording (its map from the
scans, its people replayed) and accepted. The drive is a simulated person's in a corridor with someone
walking the other way; the test publishes what the simulator saw at each step. The drive is
recorded once for the module; a copy of its bag whose demonstration stops halfway (the person
never arrives) is refused by the check, and saved only with --accept-mismatch, marked as such."""
import os
import pathlib
import sys
from typing import NamedTuple

import numpy as np
import pytest
import rosbag
import rospy
import yaml
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import LaserScan, TimeReference
from std_msgs.msg import String
from std_srvs.srv import Trigger

from robot_common.msg import People, Person
from ros_harness import wait_until
from ros_harness.launching import LaunchSet

pytestmark = pytest.mark.ros


def corridor_drive():
    """A person's drive down a 5 m corridor (test_recorded_check's): (scene, states x_0..x_T,
    actions, observations)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from test_recorded_check import corridor_scene

    from lfd_controller.sim.hallway_people import HallwayDriver
    from robot_sim.hallway import drive

    scene = corridor_scene()
    driver, seen = HallwayDriver("sampling_mpc", 0).reset(scene), []

    def policy(state, t, observation):
        seen.append(observation)
        return driver(state, t, observation)
    result = drive(scene, policy)
    assert result.success
    return scene, result.states, result.actions, seen


def messages(stamp, state, action, t, observation):
    odom = Odometry()
    odom.header.stamp = stamp
    odom.pose.pose.position.x, odom.pose.pose.position.y = state[0], state[1]
    odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = np.sin(state[2] / 2), np.cos(state[2] / 2)
    odom.twist.twist.linear.x, odom.twist.twist.angular.z = state[3], state[4]
    applied = TwistStamped()
    applied.header.stamp = stamp
    applied.twist.linear.x, applied.twist.angular.z = action
    clock = TimeReference()
    clock.header.stamp, clock.time_ref = stamp, rospy.Time.from_sec(t)
    return odom, applied, clock


def sensor_messages(stamp, observation):
    scan = LaserScan()
    scan.header.stamp = stamp
    scan.angle_min, scan.angle_increment = float(observation.angles[0]), 2 * np.pi / len(observation.angles)
    scan.range_min, scan.range_max = 0.01, 8.0
    scan.ranges = observation.ranges.tolist()
    people = People()
    people.header.stamp = stamp
    for name, where, velocity in zip(observation.names, observation.people, observation.velocities):
        person = Person(name=name)
        person.position.x, person.position.y = where
        person.velocity.x, person.velocity.y = velocity
        people.people.append(person)
    return scan, people


class RecordedBag(NamedTuple):
    """The bag the recorder wrote for corridor_drive and the drive's number of steps."""

    path: pathlib.Path
    steps: int


def publish_path(publisher, waypoints) -> None:
    """The path to follow, (x, y) waypoints, as a nav_msgs/Path in the odom frame."""
    path = Path()
    path.header.frame_id = "odom"
    for x, y in waypoints:
        pose = PoseStamped()
        pose.pose.position.x, pose.pose.position.y, pose.pose.orientation.w = x, y, 1.0
        path.poses.append(pose)
    publisher.publish(path)


def record_corridor_drive(launches: LaunchSet, bag_dir: pathlib.Path) -> RecordedBag:
    """corridor_drive through the real recorder (teleop_record.launch, no simulator): the test
    publishes odometry, applied commands, episode time, scans, people, the path and the scenario
    step by step between the recorder's start and stop."""
    from lfd_controller.hallway import hallway_scenario

    scene, states, actions, seen = corridor_drive()
    launch = launches("lfd_controller", "teleop_record.launch", with_sim="false",
                      bag_dir=str(bag_dir))
    launch.wait_for_services(["/demo_recorder/start", "/demo_recorder/stop"])
    topics = {"odom": Odometry, "cmd_vel_applied": TwistStamped, "sim_time": TimeReference,
              "scan": LaserScan, "people": People, "path": Path, "scenario": String}
    out = {name: rospy.Publisher(f"/{name}", kind, queue_size=200, latch=name in ("path", "scenario"))
           for name, kind in topics.items()}
    try:
        launch.wait_for_subscribers([f"/{name}" for name in topics], timeout=120)
        out["scenario"].publish(String(data=hallway_scenario().to_yaml()))
        publish_path(out["path"], scene.path)
        base = rospy.Time.now()
        stamps = [base + rospy.Duration.from_sec(0.1 * k) for k in range(len(states))]
        first = messages(stamps[0], states[0], (0.0, 0.0), 0.0, seen[0])
        for name, msg in zip(("odom", "cmd_vel_applied", "sim_time"), first):
            out[name].publish(msg)
        start = rospy.ServiceProxy("/demo_recorder/start", Trigger)
        wait_until(lambda: start().success, 60, what="the recorder to have the scenario and start")
        for k, action in enumerate(actions):
            for name, msg in zip(("scan", "people"), sensor_messages(stamps[k], seen[k])):
                out[name].publish(msg)
            step = messages(stamps[k + 1], states[k + 1], action, 0.1 * (k + 1), seen[k])
            for name, msg in zip(("odom", "cmd_vel_applied", "sim_time"), step):
                out[name].publish(msg)
            rospy.sleep(0.01)
        rospy.sleep(1.0)
        answer = rospy.ServiceProxy("/demo_recorder/stop", Trigger)()
        assert answer.success, answer.message
    finally:
        for publisher in out.values():     # the session's test node outlives this module
            publisher.unregister()
    return RecordedBag(next(bag_dir.glob("*.bag")), len(actions))


@pytest.fixture(scope="module")
def recorded_bag(roscore, rospy_node, tmp_path_factory) -> RecordedBag:
    """corridor_drive recorded once for the module's tests (the recorder stopped afterwards)."""
    folder = tmp_path_factory.mktemp("building_recording")
    launches = LaunchSet(roscore, folder / "launch")
    try:
        return record_corridor_drive(launches, folder / "bags")
    finally:
        launches.stop_all()


def stopped_short(bag_file: pathlib.Path, output: pathlib.Path,
                  fraction: float = 0.5) -> pathlib.Path:
    """A copy of a recorded bag whose demonstration keeps only its first `fraction` of the steps
    (the scans, people, path and every other message as recorded): a drive that stops on the way."""
    from lfd_controller import ros_demos
    from lfd_controller.demos import Demonstration

    kept, demo_msgs = [], []
    with rosbag.Bag(str(bag_file)) as bag:
        for topic, msg, stamp in bag.read_messages():
            (demo_msgs if topic == ros_demos.DEMO_TOPIC else kept).append((topic, msg, stamp))
    assert len(demo_msgs) == 1, f"{bag_file} holds {len(demo_msgs)} demonstrations"
    _, msg, _ = demo_msgs[0]
    demo = ros_demos.from_msg(msg)
    steps = int(fraction * demo.length)
    short = Demonstration(demo.scenario, demo.start, demo.actions[:steps], demo.t0,
                          demo.states[:steps], demo.source)
    return ros_demos.write_bag(output, ros_demos.to_msg(short, msg.header.stamp), kept)


def test_the_recorder_keeps_scan_people_and_path_and_a_hallway_reward_is_learned_from_the_bag(
        recorded_bag, tmp_path):
    from lfd_controller.learn_reward import main as learn_reward
    from lfd_controller.learning import load_reward

    bag_file = recorded_bag.path
    with rosbag.Bag(str(bag_file)) as bag:
        counts = {topic: info.message_count
                  for topic, info in bag.get_type_and_topic_info()[1].items()}
    assert counts["/path"] == 1
    assert min(counts["/scan"], counts["/people"]) >= 0.9 * recorded_bag.steps, counts
    output = tmp_path / "hallway_reward.yaml"
    assert learn_reward(["--bags", str(bag_file), "--kind", "hallway", "--output", str(output)]) == 0
    reward = load_reward(output)
    named = dict(zip(reward.features.names, reward.weights))
    assert reward.features.kind == "hallway" and named["path_progress"] > 0
    info = yaml.safe_load(output.read_text())["info"]
    assert info["acceptance"]["accepted"] is True, info["acceptance"]
    assert info["acceptance"]["drives"][0]["drive"] == bag_file.name
    assert info["controller"]["barrier_margin"] >= 0.1


def test_a_drive_where_the_person_never_arrived_is_refused_and_saved_only_with_accept_mismatch(
        recorded_bag, tmp_path, capsys):
    from lfd_controller import ros_demos
    from lfd_controller.learn_reward import main as learn_reward
    from lfd_controller.recorded_check import SUCCESS_TOLERANCE

    bag_file = stopped_short(recorded_bag.path, tmp_path / "stopped_halfway.bag")
    (demo, sensors), = ros_demos.read_building_bags([bag_file])
    assert np.hypot(*(demo.states[-1, :2] - sensors.path[-1])) > 2 * SUCCESS_TOLERANCE
    output = tmp_path / "hallway_reward.yaml"
    command = ["--bags", str(bag_file), "--kind", "hallway", "--output", str(output)]
    capsys.readouterr()

    assert learn_reward(command) == 1
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1, errors
    assert "NOT saved" in errors[0] and bag_file.name in errors[0], errors[0]
    assert "nothing to check the controller against" in errors[0], errors[0]
    assert "where the person succeeded" not in errors[0], errors[0]     # the person never did
    assert not output.exists()

    assert learn_reward(command + ["--accept-mismatch"]) == 0
    printed = capsys.readouterr()
    assert "ERROR:" not in printed.err
    assert "saved although NOT accepted (--accept-mismatch)" in printed.out, printed.out
    acceptance = yaml.safe_load(output.read_text())["info"]["acceptance"]
    assert acceptance["accepted"] is False, acceptance
    assert "--accept-mismatch" in acceptance["saved_anyway"], acceptance
    assert acceptance["drives"][0]["drive"] == bag_file.name
    assert acceptance["drives"][0]["person"]["success"] is False, acceptance["drives"][0]
