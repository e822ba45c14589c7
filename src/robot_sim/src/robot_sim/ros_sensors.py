"""ROS side of the sensor simulator: a mobile base patrolling a building's main hall (or waypoints
on a map file), publishing the robot's standard sensor topics, each from its own thread."""
import threading
from typing import Callable

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, JointState, LaserScan

from robot_common.maps import yaw_to_quaternion
from robot_common.ros_node import read_config
from robot_sim.building import building_or_map
from robot_sim.mobile_base import PatrolPath, SensorModel, hall_patrol
from robot_sim.params import SensorSimParams

__all__ = ["SensorSim", "run_at", "start"]


class SensorSim:
    """Publishes each sensor from its own thread at its own rate.

    Parameters (robot_sim.params.SensorSimParams, defaults in config/sensor_sim.yaml):
      ~map_yaml (""), ~seed (0): the map (empty map_yaml: the generated building, patrolling its
      main hall; a map file: patrolling ~waypoints, default [[0, 0], [1, 0]]).
      ~speed (0.5 m/s): patrol speed.
      ~odom_rate (50), ~tf_rate (50), ~scan_rate (10), ~image_rate (5), ~joint_rate (20):
      publishing rates (Hz); 0 disables a topic.
      ~scan_beams (360), ~scan_range (10.0 m): laser scanner.
      ~image_width (320), ~image_height (240): camera (rgb8).
      ~odom_frame ("odom"), ~base_frame ("base_link"), ~map_frame ("map").
    Topics (out; the robot's standard interface): odom (nav_msgs/Odometry), scan
      (sensor_msgs/LaserScan), camera/rgb/image_raw (sensor_msgs/Image), joint_states
      (sensor_msgs/JointState), /tf, /tf_static (map -> odom, base_link -> laser, camera_rgb_frame).

    Construction builds the map, the patrol path and the sensor models (MapError for an unreadable
    map file, ValueError for a bad path or sensor); `setup()` creates the publishers and starts
    the publishing threads.
    """

    def __init__(self, config: SensorSimParams):
        self.config = config
        grid, building = building_or_map(config.map_yaml, config.seed)
        self.path = hall_patrol(building, config.speed) if building is not None else \
            PatrolPath(config.waypoints, config.speed)
        self.sensors = SensorModel(grid, scan_beams=config.scan_beams, scan_range=config.scan_range,
                                   image_width=config.image_width, image_height=config.image_height)
        self.odom_frame = config.odom_frame
        self.base_frame = config.base_frame
        self.map_frame = config.map_frame

    def setup(self) -> None:
        self.start = rospy.Time.now()
        self.publishers = {
            "odom": rospy.Publisher("odom", Odometry, queue_size=100),
            "scan": rospy.Publisher("scan", LaserScan, queue_size=10),
            "image": rospy.Publisher("camera/rgb/image_raw", Image, queue_size=5),
            "joint": rospy.Publisher("joint_states", JointState, queue_size=20),
        }
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
        frames = [(self.map_frame, self.odom_frame, 0.0, 0.0),
                  (self.base_frame, "laser", 0.1, 0.2), (self.base_frame, "camera_rgb_frame", 0.05, 0.4)]
        transforms = []
        for parent, child, x, z in frames:
            transform = TransformStamped()
            transform.header.stamp = self.start
            transform.header.frame_id, transform.child_frame_id = parent, child
            transform.transform.translation.x, transform.transform.translation.z = x, z
            transform.transform.rotation.w = 1.0
            transforms.append(transform)
        self._static = tf2_ros.StaticTransformBroadcaster()
        self._static.sendTransform(transforms)

    def _state(self):
        now = rospy.Time.now()
        return now, self.path.state((now - self.start).to_sec())

    def publish_odom(self) -> None:
        now, state = self._state()
        msg = Odometry()
        msg.header.stamp, msg.header.frame_id = now, self.odom_frame
        msg.child_frame_id = self.base_frame
        pose = msg.pose.pose
        pose.position.x, pose.position.y = state.x, state.y
        (pose.orientation.x, pose.orientation.y, pose.orientation.z,
         pose.orientation.w) = yaw_to_quaternion(state.yaw)
        msg.twist.twist.linear.x, msg.twist.twist.angular.z = state.linear, state.angular
        msg.pose.covariance[0] = msg.pose.covariance[7] = 0.01
        msg.pose.covariance[35] = 0.005
        self.publishers["odom"].publish(msg)

    def publish_tf(self) -> None:
        now, state = self._state()
        transform = TransformStamped()
        transform.header.stamp, transform.header.frame_id = now, self.odom_frame
        transform.child_frame_id = self.base_frame
        transform.transform.translation.x, transform.transform.translation.y = state.x, state.y
        rotation = transform.transform.rotation
        rotation.x, rotation.y, rotation.z, rotation.w = yaw_to_quaternion(state.yaw)
        self.tf.sendTransform(transform)

    def publish_scan(self) -> None:
        now, state = self._state()
        msg = LaserScan()
        msg.header.stamp, msg.header.frame_id = now, "laser"
        msg.angle_min = float(self.sensors.scan_angles[0])
        msg.angle_max = float(self.sensors.scan_angles[-1])
        msg.angle_increment = self.sensors.scan_increment
        msg.range_min, msg.range_max = 0.05, float(self.sensors.scan_range)
        msg.ranges = self.sensors.scan(state).astype(float).tolist()
        self.publishers["scan"].publish(msg)

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


def start() -> SensorSim:
    """The node's start-up: read its parameters, build it, wire ROS."""
    sim = SensorSim(read_config(SensorSimParams))
    sim.setup()
    return sim
