"""The simulator node executables under a real roscore: they publish, or exit with one clear line."""
import math

import numpy as np
import pytest

from ros_harness import ProcessDied

pytestmark = pytest.mark.ros


def test_people_sim_publishes_people_counts(roslaunch, rospy_node):
    from robot_common.msg import PeopleCount

    sim = roslaunch("robot_sim", "people_sim.launch", rate=20.0, robots=2)
    sim.wait_for_topics(["/people_counts"], timeout=60)
    msg = rospy_node.wait_for_message("/people_counts", PeopleCount, timeout=90)
    assert msg.robot_id in ("robot_0", "robot_1") and msg.header.frame_id == "map"
    assert len(msg.cells) == len(msg.counts) == len(msg.seen_fraction) > 0


def test_object_detection_sim_publishes_its_detections_then_exits(roslaunch, rospy_node):
    from robot_common.msg import ObjectObservation
    from robot_sim.detections import building_detections, place_sightings
    from robot_sim.params import ObjectDetectionSimParams

    params = {"mean_detections": 2.0, "place_detections": 1, "rate": 2000.0}
    building, detections = building_detections(ObjectDetectionSimParams(**params))
    expected = len(detections) + len(place_sightings(building, ObjectDetectionSimParams(**params)))
    received = []
    subscribers = [rospy_node.Subscriber(topic, ObjectObservation, received.append, queue_size=5000)
                   for topic in ("/igmm_layers/observations", "/igmm_layers/place_observations")]
    try:
        sim = roslaunch.node("robot_sim", "object_detection_sim", params=params)
        sim.wait_for_exit(timeout=90)
        assert "object_detection_sim-1] process has finished cleanly" in sim.log_tail(400)
        assert len(received) == expected
    finally:
        for subscriber in subscribers:
            subscriber.unregister()


def test_a_bad_scenario_ends_the_unicycle_sim_with_one_clear_line(roslaunch):
    sim = roslaunch.node("robot_sim", "unicycle_sim", params={"scenario": "no_such_scenario"})
    with pytest.raises(ProcessDied, match="ERROR: /unicycle_sim: cannot read scenario file"):
        sim.wait_for_topics(["/odom"], timeout=90)


def test_building_sim_drives_on_cmd_vel_sees_an_added_obstacle_and_reports_the_collision(
        roslaunch, rospy_node):
    import threading

    from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped, Twist
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from ros_harness import wait_for_subscriber, wait_until

    sim = roslaunch("robot_sim", "building_sim.launch", people=0, start="[3.0, 6.7, 0.0]",
                    time_scale=2.0, with_map=False)
    sim.wait_for_topics(["/odom", "/scan", "/people", "/building_sim/status"], timeout=90)
    sim.wait_for_subscribers(["/cmd_vel", "/initialpose", "/building_sim/obstacles_in"], timeout=90)
    lock, got = threading.Lock(), {"odom": [], "status": [], "scan": None}

    def keep(key):
        def store(msg):
            with lock:
                if key == "scan":
                    got[key] = msg
                else:
                    got[key].append(msg)
        return store

    subs = [rospy_node.Subscriber("/odom", Odometry, keep("odom"), queue_size=100),
            rospy_node.Subscriber("/building_sim/status", String, keep("status")),
            rospy_node.Subscriber("/scan", LaserScan, keep("scan"), queue_size=1)]
    obstacles = rospy_node.Publisher("/building_sim/obstacles_in", PointStamped, queue_size=1)
    cmd = rospy_node.Publisher("/cmd_vel", Twist, queue_size=5)
    pose = rospy_node.Publisher("/initialpose", PoseWithCovarianceStamped, queue_size=1)
    try:
        for publisher in (obstacles, cmd, pose):
            wait_for_subscriber(publisher, "/building_sim", 60)

        def ahead():
            """The laser's range straight ahead (the two middle beams of 360 over 270 degrees)."""
            with lock:
                scan = got["scan"]
            return math.inf if scan is None else min(scan.ranges[179:181])

        def status():
            with lock:
                return got["status"][-1].data if got["status"] else ""

        wait_until(lambda: status() == "running" and ahead() == 10.0, 60, what="a clear hall ahead")
        point = PointStamped()
        point.header.frame_id, point.point.x, point.point.y = "map", 6.0, 6.7
        obstacles.publish(point)
        # the laser 0.1 m ahead of x = 3.0 meets the 0.3 m disc at x = 5.7: 2.6 m
        wait_until(lambda: abs(ahead() - 2.6) < 0.02, 60, what="the scan to see the obstacle")
        with lock:
            got["odom"].clear()
        forward = Twist()
        forward.linear.x = 0.4

        def crashed():
            cmd.publish(forward)
            return status() == "collided with clutter"
        wait_until(crashed, 120, what="a collision with the obstacle ahead")

        def standing():     # the odometry of the colliding step (topics may arrive in any order)
            with lock:
                return got["odom"] and got["odom"][-1].twist.twist.linear.x == 0.0
        wait_until(standing, 30, what="the odometry of the robot stopped by the collision")
        with lock:
            odom = list(got["odom"])
        xs = np.array([m.pose.pose.position.x for m in odom])
        speeds = np.array([m.twist.twist.linear.x for m in odom])
        # from x = 3.0 at the model's 0.4 m/s command (0.3824 m/s: its smooth speed limit) to
        # where the robot's edge (0.18 m) meets the disc (5.7), within a step of 0.019 m
        assert xs[0] < 3.05 and 5.52 < xs[-1] < 5.54
        assert 0.381 < speeds.max() < 0.384 and speeds[-1] == 0.0
        assert np.allclose([m.pose.pose.position.y for m in odom], 6.7)
        assert rospy_node.ServiceProxy("/building_sim/clear_obstacles", Trigger)().message == \
            "removed 1 obstacles"
        back = PoseWithCovarianceStamped()
        back.header.frame_id = "map"
        back.pose.pose.position.x, back.pose.pose.position.y = 3.0, 6.7
        back.pose.pose.orientation.w = 1.0
        pose.publish(back)
        wait_until(lambda: status() == "running" and ahead() == 10.0, 60,
                   what="the robot back at the start with a clear hall ahead")
    finally:
        for sub in subs:
            sub.unregister()


def test_building_sim_in_a_namespace_keeps_its_topics_and_frames_there_on_the_loop_floor(
        roslaunch, rospy_node, tmp_path):
    import tf2_ros
    from nav_msgs.msg import OccupancyGrid, Odometry
    from sensor_msgs.msg import LaserScan

    from robot_common.msg import People
    from ros_harness import wait_until

    frames = {"odom_frame": "errand_robot/odom", "base_frame": "errand_robot/base_link",
              "laser_frame": "errand_robot/laser"}
    args = "\n".join(f'      <arg name="{key}" value="{value}"/>' for key, value in
                     dict(frames, layout="loop", people=1).items())
    launch = tmp_path / "second_robot.launch"
    launch.write_text(f"""<launch>
  <group ns="errand_robot">
    <include file="$(find robot_sim)/launch/building_sim.launch">
{args}
    </include>
  </group>
</launch>
""")
    sim = roslaunch(str(launch))
    ours = ["/errand_robot/odom", "/errand_robot/scan", "/errand_robot/people",
            "/errand_robot/map", "/errand_robot/cmd_vel_applied",
            "/errand_robot/building_sim/status"]
    sim.wait_for_topics(ours, timeout=90)
    sim.wait_for_subscribers(["/errand_robot/cmd_vel", "/errand_robot/initialpose"], timeout=90)
    published = {name for name, _ in rospy_node.get_published_topics()}
    assert not published & {"/odom", "/scan", "/people", "/map", "/cmd_vel_applied"}
    grid = rospy_node.wait_for_message("/errand_robot/map", OccupancyGrid, timeout=60)
    # the loop floor: 29.9 m x 15.6 m from x = -2.5 m (see test_building)
    assert (grid.info.width, grid.info.height) == (299, 156)
    assert grid.info.origin.position.x == pytest.approx(-2.5)
    odom = rospy_node.wait_for_message("/errand_robot/odom", Odometry, timeout=60)
    assert (odom.header.frame_id, odom.child_frame_id) == (frames["odom_frame"],
                                                           frames["base_frame"])
    scan = rospy_node.wait_for_message("/errand_robot/scan", LaserScan, timeout=60)
    people = rospy_node.wait_for_message("/errand_robot/people", People, timeout=60)
    assert scan.header.frame_id == frames["laser_frame"]
    assert people.header.frame_id == frames["odom_frame"]
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer)
    try:        # map -> odom and base -> laser are static, odom -> base from each step
        wait_until(lambda: buffer.can_transform("map", frames["laser_frame"], rospy_node.Time(0)),
                   60, what="map -> laser through the configured frames")
        assert not buffer.can_transform("map", "laser", rospy_node.Time(0))
    finally:
        listener.unregister()


def test_building_sim_with_publish_clock_publishes_simulated_time_and_stamps_with_it(
        roslaunch, rospy_node, tmp_path):
    import threading

    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    from ros_harness import wait_until

    # /use_sim_time is global: a launch file of our own sets it (the harness deletes it after)
    launch = tmp_path / "sim_time.launch"
    launch.write_text("""<launch>
  <param name="/use_sim_time" value="true"/>
  <node pkg="robot_sim" type="building_sim" name="building_sim" output="screen">
    <rosparam command="load" file="$(find robot_sim)/config/building_sim.yaml"/>
    <param name="people" value="0"/>
    <param name="time_scale" value="2.0"/>
    <param name="publish_clock" value="true"/>
  </node>
</launch>
""")
    lock, stamps = threading.Lock(), {"clock": [], "odom": [], "scan": [], "static": []}

    def keep(key, stamp_of):
        def store(msg):
            with lock:
                stamps[key].append(stamp_of(msg).to_nsec())
        return store

    subs = [rospy_node.Subscriber("/clock", Clock, keep("clock", lambda m: m.clock),
                                  queue_size=100),
            rospy_node.Subscriber("/odom", Odometry, keep("odom", lambda m: m.header.stamp),
                                  queue_size=100),
            rospy_node.Subscriber("/scan", LaserScan, keep("scan", lambda m: m.header.stamp),
                                  queue_size=100)]

    def keep_static(msg):       # the simulator's own (other nodes of the session may latch some)
        if msg._connection_header.get("callerid") == "/building_sim":
            with lock:
                stamps["static"].extend(t.header.stamp.to_nsec() for t in msg.transforms)
    subs.append(rospy_node.Subscriber("/tf_static", TFMessage, keep_static, queue_size=10))
    try:
        sim = roslaunch(str(launch))
        sim.wait_for_topics(["/clock", "/odom", "/scan"], timeout=90)

        def enough():       # 2 simulated seconds on the clock, with the scans of that time
            with lock:
                return (stamps["clock"] and stamps["clock"][-1] - stamps["clock"][0] >= 2e9
                        and len(stamps["scan"]) >= 5)
        wait_until(enough, 90, what="2 simulated seconds of /clock and 5 scans")
        wait_until(lambda: stamps["static"], 30, what="the simulator's static transforms")
        with lock:
            clock, odom, scan, static = (list(stamps[key])
                                         for key in ("clock", "odom", "scan", "static"))
    finally:
        for sub in subs:
            sub.unregister()
    step, scan_period = 50_000_000, 100_000_000        # ~dt 0.05 s, ~scan_rate 10 Hz (in ns)
    # the clock advances step by step in simulated time from 0 (not wall time)
    assert all(b > a for a, b in zip(clock, clock[1:]))
    assert all(t % step == 0 for t in clock) and clock[-1] < 3600e9
    # the messages are stamped with the simulated time of their step
    seen = [t for t in odom if clock[0] <= t <= clock[-1]]
    assert len(seen) >= 10 and all(t % step == 0 for t in odom)
    assert all(t % scan_period == 0 for t in scan) and set(scan) & set(clock)
    assert static and all(t == 0 for t in static)
