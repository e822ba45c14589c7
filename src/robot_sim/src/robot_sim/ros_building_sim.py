"""ROS side of the building simulator: a robot driven by cmd_vel on a floor among walking people
(robot_sim.floor_sim.FloorSim), stepped in a thread of its own, publishing the robot's standard
topics with the helpers of robot_sim.ros_sensors."""
import threading

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String
from std_srvs.srv import Trigger, TriggerResponse

from robot_common.maps import quaternion_to_yaw
from robot_common.msg import People
from robot_common.ros_node import read_config
from robot_sim.building import building_or_map
from robot_sim.crowd import Person
from robot_sim.errors import SimError
from robot_sim.floor_sim import FloorSim, RoundPlanner, crowd_size, default_start, floor_walkers
from robot_sim.mobile_base import SensorModel
from robot_sim.params import BuildingSimParams
from robot_sim.people import PeopleSimulator
from robot_sim.ros_sensors import (
    LASER_X,
    base_transform,
    odometry_msg,
    people_msg,
    run_at,
    run_at_wall_clock,
    scan_msg,
    static_transforms,
)

__all__ = ["BuildingSim", "start"]


class BuildingSim:
    """A unicycle robot on a building floor among walking people, driven by cmd_vel.

    Parameters (robot_sim.params.BuildingSimParams, defaults in config/building_sim.yaml):
      ~map_yaml (""): a map_server file; empty: the generated building of ~seed (0), ~layout
      ("hall"; "loop": with west and north corridors round the main hall).
      ~start ([]): [x, y, yaw] in the map frame; []: the generated building's main hall 1.5 m
      from its west end facing east (a map file: a free spot drawn from ~seed).
      ~people (4): people walking rounds through the halls, from ~seed (they wait for the robot
      rather than walk into it; after 5 s they go another way round it); ~crowd_hour (-1; >= 0:
      as many people as robot_sim.people's halls hold on average at that hour of the week, at
      most ~max_people (30), ~peak_density 0.15 people/m^2).
      ~dt (0.05 s), ~time_scale (1.0 simulated s per wall s), ~command_timeout (0.5 simulated s).
      ~publish_clock (false; true: publishes /clock with the simulated time, steps x ~dt from 0,
      stamps every message and tf with it and steps on the wall clock: for /use_sim_time true).
      ~scan_rate (10 per simulated s), ~scan_beams (360 over 270 degrees), ~scan_range (10 m),
      ~people_range (8 m), ~robot_radius (0.18 m), ~obstacle_radius (0.3 m).
      ~odom_frame ("odom"), ~base_frame ("base_link"), ~map_frame ("map"), ~laser_frame
      ("laser"), ~people_frame ("odom").
    Topics in: cmd_vel (geometry_msgs/Twist), initialpose (geometry_msgs/PoseWithCovarianceStamped,
      map frame: put the robot there, standing; clears a collision), ~obstacles_in
      (geometry_msgs/PointStamped, map or odom frame: a disc of ~obstacle_radius the map lacks).
    Topics out: each step /clock (rosgraph_msgs/Clock, with ~publish_clock; before the step's
      other messages), odom (nav_msgs/Odometry; odom frame = map frame), cmd_vel_applied
      (geometry_msgs/TwistStamped: the command that moved the robot this step, zero after the
      timeout or a collision), /tf odom -> base_link; /tf_static map -> odom (identity),
      base_link -> laser (0.1 m ahead); at ~scan_rate scan (sensor_msgs/LaserScan: walls,
      clutter, people), people (robot_common/People: the people in sight within ~people_range
      with velocities, ~people_frame) and ~people_truth (robot_common/People, map frame: every
      person); latched ~status (std_msgs/String: "running" or "collided with wall|clutter|
      person": the robot stays where it hit until initialpose).
    Services: ~clear_obstacles (std_srvs/Trigger): removes the discs added on ~obstacles_in.

    Construction builds the floor, the people and the robot (MapError: unreadable map file,
    SimError: no room for people or a bad start); `setup()` wires ROS and starts stepping at
    time_scale / dt steps per wall-clock second (without ~publish_clock on ROS time: under
    /use_sim_time another node's /clock paces it).
    """

    def __init__(self, config: BuildingSimParams):
        self.config = config
        grid, building = building_or_map(config.map_yaml, config.seed, config.layout)
        start = config.start or default_start(grid, building, config.seed)
        self.sensors = SensorModel(grid, scan_beams=config.scan_beams, scan_range=config.scan_range)
        count, crowd = config.people, None
        if config.crowd_hour >= 0:
            sim = PeopleSimulator.from_building(building, 0.5, peak_density=config.peak_density) \
                if building is not None else \
                PeopleSimulator.from_map(grid, 0.5, peak_density=config.peak_density)
            crowd = (sim, config.crowd_hour)
            count = min(config.max_people, int(round(crowd_size(sim, config.crowd_hour))))
        planner = RoundPlanner(grid, config.seed, building=building, crowd=crowd)
        walkers = floor_walkers(planner, count, keep_clear=start[:2])
        self.sim = FloorSim(grid, walkers, start, dt=config.dt,
                            command_timeout=config.command_timeout,
                            robot_radius=config.robot_radius, laser_x=LASER_X, planner=planner)
        self.scan_every = max(1, int(round(1.0 / (config.scan_rate * config.dt))))
        self.lock = threading.Lock()
        self._last_status = None

    def setup(self) -> None:
        pub, config = rospy.Publisher, self.config
        self.odom = pub("odom", Odometry, queue_size=20)
        self.applied = pub("cmd_vel_applied", TwistStamped, queue_size=20)
        self.scan = pub("scan", LaserScan, queue_size=5)
        self.people = pub("people", People, queue_size=5)
        self.truth = pub("~people_truth", People, queue_size=5)
        self.status = pub("~status", String, queue_size=5, latch=True)
        self.clock = pub("/clock", Clock, queue_size=10) if config.publish_clock else None
        _warn_of_clock_mismatch(config.publish_clock, bool(rospy.get_param("/use_sim_time", False)))
        self.tf = tf2_ros.TransformBroadcaster()
        self._static = tf2_ros.StaticTransformBroadcaster()
        self._static.sendTransform(static_transforms(self._stamp(self.sim.steps), [
            (config.map_frame, config.odom_frame, 0.0, 0.0),
            (config.base_frame, config.laser_frame, LASER_X, 0.2)]))
        rospy.Subscriber("cmd_vel", Twist, self.on_cmd, queue_size=5)
        rospy.Subscriber("initialpose", PoseWithCovarianceStamped, self.on_pose, queue_size=1)
        rospy.Subscriber("~obstacles_in", PointStamped, self.on_obstacle, queue_size=10)
        rospy.Service("~clear_obstacles", Trigger, self.on_clear)
        # rospy.Rate follows /clock under /use_sim_time: with ~publish_clock only this loop
        # advances it, so it runs on the wall clock
        loop = run_at_wall_clock if config.publish_clock else run_at
        loop(config.time_scale / config.dt, self.step)

    def on_cmd(self, msg: Twist) -> None:
        with self.lock:
            try:
                self.sim.set_command(msg.linear.x, msg.angular.z)
            except SimError as err:
                rospy.logwarn_throttle(5.0, f"building_sim: ignored a command: {err}")

    def on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        p = msg.pose.pose
        yaw = quaternion_to_yaw(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
        with self.lock:
            try:
                self.sim.place([p.position.x, p.position.y, yaw])
            except SimError as err:
                rospy.logwarn(f"building_sim: ignored initialpose: {err}")
                return
            status = self.sim.status
        rospy.loginfo(f"building_sim: robot put at ({p.position.x:.2f}, {p.position.y:.2f}, "
                      f"{yaw:.2f}): {status}")

    def on_obstacle(self, msg: PointStamped) -> None:
        frame = msg.header.frame_id.lstrip("/")
        if frame not in ("", self.config.map_frame, self.config.odom_frame):
            rospy.logwarn(f"building_sim: ignored an obstacle in frame {frame!r} (give it in "
                          f"{self.config.map_frame!r})")
            return
        with self.lock:
            try:
                count = self.sim.add_obstacle(msg.point.x, msg.point.y, self.config.obstacle_radius)
            except SimError as err:
                rospy.logwarn(f"building_sim: ignored an obstacle: {err}")
                return
        rospy.loginfo(f"building_sim: obstacle {count} at ({msg.point.x:.2f}, {msg.point.y:.2f})")

    def on_clear(self, _request) -> TriggerResponse:
        with self.lock:
            count = self.sim.clear_obstacles()
        return TriggerResponse(True, f"removed {count} obstacles")

    def step(self) -> None:
        with self.lock:
            applied = self.sim.step()
            state, status, steps = self.sim.state.copy(), self.sim.status, self.sim.steps
            seen = self._sense() if steps % self.scan_every == 0 else None
        stamp, config = self._stamp(steps), self.config
        if self.clock is not None:      # first, so the stamps below are never ahead of /clock
            self.clock.publish(Clock(clock=stamp))
        self.odom.publish(odometry_msg(stamp, config.odom_frame, config.base_frame, *state))
        self.tf.sendTransform(base_transform(stamp, config.odom_frame, config.base_frame,
                                             *state[:3]))
        cmd = TwistStamped()
        cmd.header.stamp, cmd.header.frame_id = stamp, config.base_frame
        cmd.twist.linear.x, cmd.twist.angular.z = (float(v) for v in applied)
        self.applied.publish(cmd)
        if seen is not None:
            ranges, tracked, truth = seen
            self.scan.publish(scan_msg(stamp, config.laser_frame, self.sensors, ranges))
            self.people.publish(_people(tracked, stamp, config.people_frame))
            self.truth.publish(_people(truth, stamp, config.map_frame))
        if status != self._last_status:
            self.status.publish(String(data=status))
            self._last_status = status

    def _stamp(self, steps: int) -> rospy.Time:
        """The stamp after `steps` steps: the simulated time with ~publish_clock, else ROS time.

        Simulated time starts at 0 as in Gazebo and Stage, which is what nodes under
        /use_sim_time expect: the same seed gives the same stamps on every run, and no stamp
        passes for wall time (in a bag, beside real data)."""
        if self.clock is None:
            return rospy.Time.now()
        return rospy.Time(0, int(round(steps * self.config.dt * 1e9)))

    def _sense(self):
        """(ranges, tracked people, all people) now: called under the lock."""
        return (self.sim.scan(self.sensors.scan_angles, self.sensors.scan_range),
                self.sim.tracked(self.config.people_range), self.sim.truth())


def _warn_of_clock_mismatch(publish_clock: bool, use_sim_time: bool) -> None:
    """One warning at start-up when the simulator and the other nodes disagree on the clock."""
    if use_sim_time and not publish_clock:
        rospy.logwarn("building_sim: /use_sim_time is true but ~publish_clock is false: this "
                      "node will not publish /clock and waits for another node's (set "
                      "~publish_clock true to have the simulator publish it)")
    elif publish_clock and not use_sim_time:
        rospy.logwarn("building_sim: ~publish_clock is true but /use_sim_time is false: the "
                      "other nodes run on wall time while the stamps are simulated time from 0")


def _people(report, stamp, frame_id: str) -> People:
    names, positions, velocities = report
    people = [Person(name, float(x), float(y)) for name, (x, y) in zip(names, positions)]
    return people_msg(people, stamp, frame_id, np.asarray(velocities).tolist())


def start() -> BuildingSim:
    """The node's start-up: read its parameters, build it, wire ROS."""
    sim = BuildingSim(read_config(BuildingSimParams))
    sim.setup()
    return sim
