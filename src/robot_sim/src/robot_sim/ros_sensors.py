"""ROS side of the sensor simulator: a mobile base patrolling a building's main hall (or waypoints
on a map file), publishing the robot's standard sensor topics, each from its own thread."""
import math
import threading
import time
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import Point, TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, JointState, LaserScan

from robot_common.cells import hours_of_week
from robot_common.maps import yaw_to_quaternion
from robot_common.msg import People
from robot_common.msg import Person as PersonMsg
from robot_common.ros_node import read_config
from robot_sim.building import building_or_map
from robot_sim.crowd import Crowd, Person, Tracker
from robot_sim.mobile_base import PatrolPath, SensorModel, hall_patrol
from robot_sim.params import SensorSimParams
from robot_sim.people import PeopleSimulator

__all__ = ["SensorSim", "LASER_X", "people_msg", "odometry_msg", "base_transform", "scan_msg",
           "static_transforms", "run_at", "run_at_wall_clock", "start"]

LASER_X = 0.1      # the laser is this far ahead of base_link (the static base_link -> laser tf)


class SensorSim:
    """Publishes each sensor from its own thread at its own rate.

    Parameters (robot_sim.params.SensorSimParams, defaults in config/sensor_sim.yaml):
      ~map_yaml (""), ~seed (0), ~layout ("hall" or "loop"): the map (empty map_yaml: the
      generated building, patrolling its main hall; a map file: patrolling ~waypoints,
      default [[0, 0], [1, 0]]).
      ~speed (0.5 m/s): patrol speed.
      ~odom_rate (50), ~tf_rate (50), ~scan_rate (10), ~image_rate (5), ~joint_rate (20):
      publishing rates (Hz); 0 disables a topic.
      ~scan_beams (360), ~scan_range (10.0 m): laser scanner.
      ~image_width (320), ~image_height (240): camera (rgb8).
      ~odom_frame ("odom"), ~base_frame ("base_link"), ~map_frame ("map"), ~laser_frame ("laser").
      ~crowd (false; true: people in the halls, `robot_sim.crowd`): ~crowd_hour (-1: the stamps'
      time of week, UTC; else the hour of the week the densities are held at), ~peak_density
      (0.15 people/m^2), ~crowd_seed (1), ~person_radius (0.25 m), the tracker's ~miss_rate
      (0.1), ~false_positive_rate (0.1), ~false_track_scans (2), ~tracker_noise (0.05 m),
      ~people_frame ("odom").
    Topics (out; the robot's standard interface): odom (nav_msgs/Odometry), scan
      (sensor_msgs/LaserScan; with ~crowd the people in it), camera/rgb/image_raw
      (sensor_msgs/Image), joint_states (sensor_msgs/JointState), /tf, /tf_static (map -> odom,
      base_link -> laser, camera_rgb_frame). With ~crowd, with each scan and its stamp: people
      (robot_common/People, the tracker's report, names are track ids) and ~people_truth
      (robot_common/People, map frame: the true people the laser sees).

    Construction builds the map, the patrol path and the sensor models (MapError for an unreadable
    map file, ValueError for a bad path or sensor); `setup()` creates the publishers and starts
    the publishing threads.
    """

    def __init__(self, config: SensorSimParams):
        self.config = config
        grid, building = building_or_map(config.map_yaml, config.seed, config.layout)
        self.path = hall_patrol(building, config.speed) if building is not None else \
            PatrolPath(config.waypoints, config.speed)
        self.sensors = SensorModel(grid, scan_beams=config.scan_beams, scan_range=config.scan_range,
                                   image_width=config.image_width, image_height=config.image_height)
        self.odom_frame = config.odom_frame
        self.base_frame = config.base_frame
        self.map_frame = config.map_frame
        self.crowd: Optional[Crowd] = None
        if config.crowd:
            options = dict(seed=config.crowd_seed, peak_density=config.peak_density)
            sim = PeopleSimulator.from_building(building, 0.5, **options) if building is not None \
                else PeopleSimulator.from_map(grid, 0.5, **options)
            self.crowd = Crowd(sim, radius=config.person_radius, seed=config.crowd_seed)
            self.tracker = Tracker(miss_rate=config.miss_rate,
                                   false_positive_rate=config.false_positive_rate,
                                   false_track_scans=config.false_track_scans,
                                   noise=config.tracker_noise, seed=config.crowd_seed + 1)
        self._crowd_lock = threading.Lock()

    def setup(self) -> None:
        self.start = rospy.Time.now()
        self.publishers = {
            "odom": rospy.Publisher("odom", Odometry, queue_size=100),
            "scan": rospy.Publisher("scan", LaserScan, queue_size=10),
            "image": rospy.Publisher("camera/rgb/image_raw", Image, queue_size=5),
            "joint": rospy.Publisher("joint_states", JointState, queue_size=20),
        }
        if self.crowd is not None:
            self.publishers["people"] = rospy.Publisher("people", People, queue_size=10)
            self.publishers["truth"] = rospy.Publisher("~people_truth", People, queue_size=10)
        self.tf = tf2_ros.TransformBroadcaster()
        self._publish_static_frames()
        config = self.config
        for rate, publish in ((config.odom_rate, self.publish_odom), (config.tf_rate, self.publish_tf),
                              (config.scan_rate, self.publish_scan),
                              (config.image_rate, self.publish_image),
                              (config.joint_rate, self.publish_joints)):
            if rate > 0:
                run_at(rate, publish)

    def _publish_static_frames(self) -> None:
        self._static = tf2_ros.StaticTransformBroadcaster()
        self._static.sendTransform(static_transforms(self.start, [
            (self.map_frame, self.odom_frame, 0.0, 0.0),
            (self.base_frame, self.config.laser_frame, LASER_X, 0.2),
            (self.base_frame, "camera_rgb_frame", 0.05, 0.4)]))

    def _state(self):
        now = rospy.Time.now()
        return now, self.path.state((now - self.start).to_sec())

    def publish_odom(self) -> None:
        now, state = self._state()
        self.publishers["odom"].publish(odometry_msg(now, self.odom_frame, self.base_frame, state.x,
                                                     state.y, state.yaw, state.linear, state.angular))

    def publish_tf(self) -> None:
        now, state = self._state()
        self.tf.sendTransform(base_transform(now, self.odom_frame, self.base_frame, state.x, state.y,
                                             state.yaw))

    def publish_scan(self) -> None:
        now, state = self._state()
        frame = self.config.laser_frame
        if self.crowd is None:
            self.publishers["scan"].publish(scan_msg(now, frame, self.sensors,
                                                     self.sensors.scan(state)))
            return
        ranges, report, truth = self._crowd_scan(now, state)
        self.publishers["scan"].publish(scan_msg(now, frame, self.sensors, ranges))
        self.publishers["people"].publish(people_msg(report, now, self.config.people_frame))
        self.publishers["truth"].publish(people_msg(truth, now, self.map_frame))

    def _crowd_scan(self, now, state):
        """The crowd moved on to `now`, seen by the laser: (ranges, tracker report, truth)."""
        seconds = now.to_sec()
        hours = self.config.crowd_hour if self.config.crowd_hour >= 0 else \
            float(hours_of_week(seconds, 0.0))
        pose = (state.x + LASER_X * math.cos(state.yaw), state.y + LASER_X * math.sin(state.yaw),
                state.yaw)
        with self._crowd_lock:
            self.crowd.advance(seconds, hours)
            return self.tracker.scan(self.sensors.grid, self.crowd, pose, self.sensors.scan_angles,
                                     self.sensors.scan_range)

    def publish_image(self) -> None:
        now, state = self._state()
        pixels = self.sensors.image(state)
        msg = Image()
        msg.header.stamp, msg.header.frame_id = now, "camera_rgb_frame"
        msg.height, msg.width = pixels.shape[:2]
        msg.encoding, msg.is_bigendian, msg.step = "rgb8", 0, pixels.shape[1] * 3
        msg.data = pixels.tobytes()
        self.publishers["image"].publish(msg)

    def publish_joints(self) -> None:
        now, state = self._state()
        msg = JointState()
        msg.header.stamp = now
        msg.name = ["wheel_left_joint", "wheel_right_joint"]
        msg.position = self.sensors.wheel_angles((now - self.start).to_sec(), state)
        msg.velocity = [state.linear / self.sensors.wheel_radius] * 2
        self.publishers["joint"].publish(msg)


def people_msg(people: List[Person], stamp, frame_id: str,
               velocities: Optional[Sequence[Sequence[float]]] = None) -> People:
    """robot_common/People of `people` (names, positions; `velocities` (vx, vy) each, default 0;
    reliability 1)."""
    msg = People()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    velocities = [(0.0, 0.0)] * len(people) if velocities is None else velocities
    msg.people = [PersonMsg(name=p.name, position=Point(p.x, p.y, 0.0),
                            velocity=Point(float(v[0]), float(v[1]), 0.0), reliability=1.0)
                  for p, v in zip(people, velocities)]
    return msg


def odometry_msg(stamp, frame_id: str, child: str, x: float, y: float, yaw: float,
                 linear: float, angular: float) -> Odometry:
    """nav_msgs/Odometry of a planar pose and speeds (small fixed pose covariance)."""
    msg = Odometry()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.child_frame_id = child
    pose = msg.pose.pose
    pose.position.x, pose.position.y = float(x), float(y)
    (pose.orientation.x, pose.orientation.y, pose.orientation.z,
     pose.orientation.w) = yaw_to_quaternion(float(yaw))
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = float(linear), float(angular)
    msg.pose.covariance[0] = msg.pose.covariance[7] = 0.01
    msg.pose.covariance[35] = 0.005
    return msg


def base_transform(stamp, frame_id: str, child: str, x: float, y: float,
                   yaw: float) -> TransformStamped:
    """The planar transform frame_id -> child (odom -> base_link)."""
    transform = TransformStamped()
    transform.header.stamp, transform.header.frame_id = stamp, frame_id
    transform.child_frame_id = child
    transform.transform.translation.x, transform.transform.translation.y = float(x), float(y)
    rotation = transform.transform.rotation
    rotation.x, rotation.y, rotation.z, rotation.w = yaw_to_quaternion(float(yaw))
    return transform


def static_transforms(stamp, frames: Sequence[Tuple[str, str, float, float]]
                      ) -> List[TransformStamped]:
    """Fixed transforms (parent, child, x ahead, z up), no rotation."""
    transforms = []
    for parent, child, x, z in frames:
        transform = TransformStamped()
        transform.header.stamp = stamp
        transform.header.frame_id, transform.child_frame_id = parent, child
        transform.transform.translation.x, transform.transform.translation.z = x, z
        transform.transform.rotation.w = 1.0
        transforms.append(transform)
    return transforms


def scan_msg(stamp, frame_id: str, sensors: SensorModel, ranges) -> LaserScan:
    """sensor_msgs/LaserScan of `ranges` along the angles of `sensors` (a SensorModel)."""
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.angle_min = float(sensors.scan_angles[0])
    msg.angle_max = float(sensors.scan_angles[-1])
    msg.angle_increment = sensors.scan_increment
    msg.range_min, msg.range_max = 0.05, float(sensors.scan_range)
    msg.ranges = np.asarray(ranges, float).tolist()
    return msg


def run_at(rate_hz: float, publish: Callable[[], None]) -> threading.Thread:
    """A daemon thread calling `publish()` at `rate_hz` until ROS shuts down."""
    def loop():
        rate = rospy.Rate(rate_hz)
        while not rospy.is_shutdown():
            publish()
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break
    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def run_at_wall_clock(rate_hz: float, publish: Callable[[], None]) -> threading.Thread:
    """`run_at` on the wall clock even with /use_sim_time true: for the node that publishes /clock
    (a rospy.Rate would wait for the clock this loop advances). Like rospy.Rate, a loop more than
    a period late starts again from now instead of catching up in a burst."""
    if not rate_hz > 0:
        raise ValueError(f"a loop's rate must be positive, got {rate_hz}")
    period = 1.0 / rate_hz
    stopped = threading.Event()
    rospy.on_shutdown(stopped.set)

    def loop():
        due = time.monotonic()
        while not rospy.is_shutdown():
            publish()
            due += period
            now = time.monotonic()
            if now - due > period:
                due = now
            if stopped.wait(max(0.0, due - now)):
                break
    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def start() -> SensorSim:
    """The node's start-up: read its parameters, build it, wire ROS."""
    sim = SensorSim(read_config(SensorSimParams))
    sim.setup()
    return sim
