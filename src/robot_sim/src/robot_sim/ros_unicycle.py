"""ROS side of the unicycle simulator: one navigation scenario (robot_common.tasks) stepped in
real time (scaled), driven by cmd_vel, with its episode state from robot_sim.scenarios.SimEpisode."""
import threading

import rospy
import tf2_ros
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import TimeReference
from std_msgs.msg import String
from std_srvs.srv import Trigger, TriggerResponse
from visualization_msgs.msg import Marker, MarkerArray

from robot_common.maps import quaternion_to_yaw, yaw_to_quaternion
from robot_common.ros_node import read_config
from robot_sim.errors import SimError
from robot_sim.params import UnicycleSimParams
from robot_sim.ros_sensors import base_transform, odometry_msg
from robot_sim.scenarios import SimEpisode, load_scenario

__all__ = ["UnicycleSim", "start"]


def _pose(target, x, y, yaw):
    target.position.x, target.position.y = float(x), float(y)
    q = target.orientation
    q.x, q.y, q.z, q.w = yaw_to_quaternion(float(yaw))


class UnicycleSim:
    """A turtlebot-like unicycle driving to a goal past one static or moving obstacle.

    Parameters (robot_sim.params.UnicycleSimParams, defaults in config/unicycle_sim.yaml):
      ~scenario ("static_obstacle"): a scenario name (robot_sim config/scenarios) or YAML path.
      ~seed (0): random starts. ~start ([]): [x, y, yaw] of the first episode; []: random.
      ~time_scale (1.0): simulated seconds per wall-clock second.
      ~command_timeout (0.5): seconds after which a silent cmd_vel means stop.
      ~odom_frame ("odom"), ~base_frame ("base_link").
    Topics in: cmd_vel (geometry_msgs/Twist), initialpose (geometry_msgs/PoseWithCovarianceStamped:
      restart the episode there).
    Topics out (all stamped alike per step): odom (nav_msgs/Odometry), cmd_vel_applied
      (geometry_msgs/TwistStamped: the command that produced this odom), sim_time
      (sensor_msgs/TimeReference: time_ref = episode time), obstacle (nav_msgs/Odometry), /tf;
      latched: goal (geometry_msgs/PoseStamped), scenario (std_msgs/String, YAML), ~status
      (std_msgs/String: "<episode> running|reached|collided"); markers
      (visualization_msgs/MarkerArray, only while someone listens).
    Services: ~reset (std_srvs/Trigger): a new episode from a random start.

    Construction loads the scenario and starts the first episode (TaskError for a bad scenario,
    SimError for a bad start); `setup()` wires ROS and starts stepping at
    time_scale / dt steps per second in a thread of its own.
    """

    def __init__(self, config: UnicycleSimParams):
        self.config = config
        self.episode = SimEpisode(load_scenario(config.scenario), seed=config.seed,
                                  command_timeout=config.command_timeout)
        if config.start:
            self.episode.reset(config.start)
        self.lock = threading.Lock()
        self.odom_frame = config.odom_frame
        self.base_frame = config.base_frame

    def setup(self) -> None:
        pub = rospy.Publisher
        self.odom = pub("odom", Odometry, queue_size=20)
        self.applied = pub("cmd_vel_applied", TwistStamped, queue_size=20)
        self.clock = pub("sim_time", TimeReference, queue_size=20)
        self.obstacle = pub("obstacle", Odometry, queue_size=20)
        self.markers = pub("markers", MarkerArray, queue_size=2)
        self.goal = pub("goal", PoseStamped, queue_size=1, latch=True)
        self.scenario = pub("scenario", String, queue_size=1, latch=True)
        self.status = pub("~status", String, queue_size=5, latch=True)
        self.tf = tf2_ros.TransformBroadcaster()
        self._last_status = None
        rospy.Subscriber("cmd_vel", Twist, self.on_cmd, queue_size=5)
        rospy.Subscriber("initialpose", PoseWithCovarianceStamped, self.on_pose, queue_size=1)
        rospy.Service("~reset", Trigger, self.on_reset)
        self.publish_latched()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        rate = rospy.Rate(self.config.time_scale / self.episode.scenario.dt)
        while not rospy.is_shutdown():
            self.step()
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break

    def publish_latched(self):
        goal = PoseStamped()
        goal.header.stamp, goal.header.frame_id = rospy.Time.now(), self.odom_frame
        _pose(goal.pose, *self.episode.scenario.goal, 0.0)
        self.goal.publish(goal)
        self.scenario.publish(String(data=self.episode.scenario.to_yaml()))

    def on_cmd(self, msg):
        with self.lock:
            try:
                self.episode.set_command(msg.linear.x, msg.angular.z)
            except SimError as err:
                rospy.logwarn_throttle(5.0, f"unicycle_sim: ignored command: {err}")

    def on_pose(self, msg):
        p = msg.pose.pose
        with self.lock:
            self.episode.reset([p.position.x, p.position.y,
                                quaternion_to_yaw(p.orientation.x, p.orientation.y, p.orientation.z,
                                                  p.orientation.w)])

    def on_reset(self, _request):
        with self.lock:
            state = self.episode.reset()
        return TriggerResponse(True, f"episode {self.episode.episode} from x={state[0]:.2f} "
                                     f"y={state[1]:.2f} yaw={state[2]:.2f}")

    def step(self):
        with self.lock:
            applied = self.episode.step()
            state, t, status = self.episode.state.copy(), self.episode.time, self.episode.status
            label = f"{self.episode.episode} {status}"
        stamp = rospy.Time.now()
        ref = TimeReference(time_ref=rospy.Time.from_sec(t), source="unicycle_sim")
        ref.header.stamp = stamp
        self.clock.publish(ref)
        cmd = TwistStamped()
        cmd.header.stamp, cmd.header.frame_id = stamp, self.base_frame
        cmd.twist.linear.x, cmd.twist.angular.z = applied
        self.applied.publish(cmd)
        self.odom.publish(odometry_msg(stamp, self.odom_frame, self.base_frame, *state[:5]))
        obstacle = self.episode.scenario.obstacle
        (vx, vy), (ox, oy) = obstacle.velocity_at(t), obstacle.position(t)
        msg = odometry_msg(stamp, self.odom_frame, "obstacle", ox, oy, 0.0, 0.0, 0.0)
        msg.twist.twist.linear.x, msg.twist.twist.linear.y = vx, vy
        self.obstacle.publish(msg)
        self.tf.sendTransform(base_transform(stamp, self.odom_frame, self.base_frame, *state[:3]))
        if label != self._last_status:
            self.status.publish(String(data=label))
            self._last_status = label
        if self.markers.get_num_connections() > 0:
            self.markers.publish(self.marker_array(stamp, state, (ox, oy)))

    def marker_array(self, stamp, state, obstacle_xy):
        scenario = self.episode.scenario
        items = [("robot", state[:2], scenario.robot_radius, (0.2, 0.4, 1.0)),
                 ("obstacle", obstacle_xy, scenario.obstacle.radius, (1.0, 0.3, 0.2)),
                 ("goal", scenario.goal, scenario.goal_tolerance, (0.2, 0.9, 0.3))]
        array = MarkerArray()
        for index, (name, (x, y), radius, (red, green, blue)) in enumerate(items):
            marker = Marker(type=Marker.CYLINDER, action=Marker.ADD, ns=name, id=index)
            marker.header.stamp, marker.header.frame_id = stamp, self.odom_frame
            _pose(marker.pose, x, y, 0.0)
            marker.scale.x = marker.scale.y = 2.0 * radius
            marker.scale.z = 0.1
            marker.color.r, marker.color.g, marker.color.b, marker.color.a = red, green, blue, 0.8
            array.markers.append(marker)
        return array


def start() -> UnicycleSim:
    """The node's start-up: read its parameters, build it, wire ROS."""
    sim = UnicycleSim(read_config(UnicycleSimParams))
    sim.setup()
    return sim
