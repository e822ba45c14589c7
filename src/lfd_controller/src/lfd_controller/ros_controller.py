"""RewardControllerNode: drives with a learned reward by receding-horizon optimisation."""
import threading
import time
from collections import deque

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import TimeReference
from std_msgs.msg import Float64, String
from std_srvs.srv import SetBool, SetBoolResponse
from threadpoolctl import threadpool_limits

from lfd_controller.features import ACCEL_MEMORY, ACCEL_SPAN, Task, observed_acceleration
from lfd_controller.hallway_features import HallwayFeatures
from lfd_controller.learning import controller_settings, load_reward
from lfd_controller.params import RewardControllerParams
from lfd_controller.planner import CollisionBarrier, RecedingHorizonController
from lfd_controller.ros_hallway_controller import HallwayControllerNode
from robot_common.errors import ModelError, TaskError
from robot_common.ros_node import odom_state, path_msg, read_config
from robot_common.tasks import scenario_from_yaml
from robot_common.unicycle import Unicycle


class RewardControllerNode:
    """Re-plans from the latest odometry at ~rate Hz and publishes the first command (a reward
    learned over the one-obstacle features; a hallway reward runs ros_hallway_controller's
    HallwayControllerNode instead: path, scan, people, map).

    Parameters (lfd_controller.params.RewardControllerParams; config/reward_controller.yaml):
      ~reward_file (str, required): a reward saved by learn_reward,
      ~rate (double, 10), ~horizon (int, 20), ~plan_dt (double, 0.2), ~terminal (double, 10),
      ~max_iter (int, 15), ~goal_tolerance (double, 0.25): stop (zero command) inside it,
      ~v_max, ~w_max, ~a_max, ~alpha_max: the robot's limits (the scenario's when one is received),
      ~obstacle_radius (double, 0.25), ~robot_radius (double, 0.18), ~collision_margin (double,
      0: > 0 adds planner.CollisionBarrier at robot + obstacle radius + margin to the reward),
      ~detour (double, 0: > 0 adds planner.detour_seeds this far beside the obstacle),
      ~frame (str, "odom"), ~enabled (bool, true).
    Topics in: odom (nav_msgs/Odometry), goal (geometry_msgs/PoseStamped), obstacle
      (nav_msgs/Odometry: position and velocity; predicted at constant velocity, the barrier
      widened for a change of velocity as hard as the hardest in its last 2 s, at least
      ~obstacle_accel), scenario
      (std_msgs/String; optional: time-indexed obstacle and limits from the simulator's scenario),
      sim_time (sensor_msgs/TimeReference; optional: episode time for the scenario's obstacle).
      Without sim_time the episode time is wall-clock (monotonic) seconds since driving was
      enabled, so the warm start shifts with real time.
    Topics out: cmd_vel (geometry_msgs/Twist), ~plan (nav_msgs/Path, while someone listens),
      ~cycle_time (std_msgs/Float64: seconds spent planning each cycle; the budget is 1/rate:
      alternative seeds are skipped when the warm start used half of it, overruns are warned).
    Services: ~enable (std_srvs/SetBool): start or stop driving (stopping publishes a zero command).
    """

    def __init__(self, reward, config: RewardControllerParams):
        self.reward, self.lock = reward, threading.Lock()
        self.config = config
        self.frame = config.frame
        self.tolerance = config.goal_tolerance
        self.obstacle_radius = config.obstacle_radius
        self.enabled = config.enabled
        self.options = config.controller_options()
        self.options["budget"] = 1.0 / config.rate
        clearance = config.robot_radius + config.obstacle_radius
        self.controller = RecedingHorizonController(self.planned_reward(clearance),
                                                    Unicycle(0.1, config.limits()), **self.options)
        self.clock_origin = time.monotonic()     # wall-clock episode time without sim_time
        self.state = self.goal = self.obstacle = self.scenario = self.episode_time = None
        self.obstacle_track = deque()      # (monotonic time, velocity) of the obstacle topic
        self.cmd = self.plan = self.cycle = self.timer = None

    def planned_reward(self, clearance: float):
        """The learned reward, plus the collision barrier when ~collision_margin > 0."""
        if self.config.collision_margin > 0:
            return CollisionBarrier(self.reward, clearance, margin=self.config.collision_margin)
        return self.reward

    def setup(self) -> "RewardControllerNode":
        """Publishers, subscribers, the ~enable service and the control timer."""
        self.cmd = rospy.Publisher("cmd_vel", Twist, queue_size=5)
        self.plan = rospy.Publisher("~plan", Path, queue_size=2)
        self.cycle = rospy.Publisher("~cycle_time", Float64, queue_size=10)
        rospy.Subscriber("odom", Odometry, self.on_odom, queue_size=1)
        rospy.Subscriber("goal", PoseStamped, self.on_goal, queue_size=1)
        rospy.Subscriber("obstacle", Odometry, self.on_obstacle, queue_size=1)
        rospy.Subscriber("scenario", String, self.on_scenario, queue_size=1)
        rospy.Subscriber("sim_time", TimeReference, self.on_time, queue_size=1)
        rospy.Service("~enable", SetBool, self.on_enable)
        self.timer = rospy.Timer(rospy.Duration(1.0 / self.config.rate), self.tick)
        return self

    def on_odom(self, msg):
        with self.lock:
            self.state = (np.array(odom_state(msg)), time.monotonic())

    def on_goal(self, msg):
        with self.lock:
            self.goal = np.array([msg.pose.position.x, msg.pose.position.y])

    def on_obstacle(self, msg):
        twist = msg.twist.twist
        now = time.monotonic()
        with self.lock:
            self.obstacle = (np.array([msg.pose.pose.position.x, msg.pose.pose.position.y]),
                             np.array([twist.linear.x, twist.linear.y]), now)
            self.obstacle_track.append((now, self.obstacle[1]))
            while self.obstacle_track[0][0] < now - ACCEL_MEMORY - ACCEL_SPAN:
                self.obstacle_track.popleft()

    def on_scenario(self, msg):
        try:
            scenario = scenario_from_yaml(msg.data)
        except (TaskError, ModelError) as err:
            rospy.logwarn(f"reward_controller: ignored scenario: {err}")
            return
        with self.lock:
            self.scenario = scenario
            self.controller = RecedingHorizonController(self.planned_reward(scenario.clearance),
                                                        scenario.model(), **self.options)

    def on_time(self, msg):
        with self.lock:
            self.episode_time = (msg.time_ref.to_sec(), time.monotonic())

    def on_enable(self, request):
        with self.lock:
            self.enabled = bool(request.data)
            self.controller.reset()
            self.clock_origin = time.monotonic()
        if not request.data:
            self.cmd.publish(Twist())
        return SetBoolResponse(True, "driving" if request.data else "stopped")

    def task_now(self):
        """(Task, episode time) from what is known: the scenario's time-indexed obstacle when the
        simulator's time is known, else a constant-velocity prediction from the obstacle topic."""
        now = time.monotonic()
        if self.scenario is not None and self.episode_time is not None:
            t = self.episode_time[0]      # the episode time of the latest step (odom comes with it)
            goal = self.goal if self.goal is not None else self.scenario.goal
            return Task(goal, self.scenario.obstacle.position, self.scenario.obstacle.radius), t
        t = now - self.clock_origin
        if self.goal is None or self.obstacle is None:
            return None, t
        position, velocity, seen = self.obstacle
        accel = self.config.obstacle_accel
        if self.obstacle_track:
            times, velocities = zip(*self.obstacle_track)
            accel = max(accel, observed_acceleration(times, velocities))
        return Task.constant_velocity(self.goal, position + velocity * (now - seen), velocity, t,
                                      self.obstacle_radius, accel), t

    def tick(self, _event):
        with self.lock:
            if not self.enabled or self.state is None:
                return
            state = self.state[0]
            task, t = self.task_now()
        if task is None:
            rospy.logwarn_throttle(5.0, "reward_controller: waiting for goal and obstacle")
            return
        twist = Twist()
        if np.linalg.norm(state[:2] - task.goal) > self.tolerance:
            started = time.perf_counter()
            twist.linear.x, twist.angular.z = self.controller.act(state, t, task)
            spent = time.perf_counter() - started
            self.cycle.publish(Float64(spent))
            if spent > self.controller.budget:
                rospy.logwarn_throttle(10.0, f"reward_controller: a cycle took {spent * 1000:.0f} ms, "
                                             f"over the {self.controller.budget * 1000:.0f} ms budget "
                                             f"({self.controller.overruns_} overruns so far)")
        self.cmd.publish(twist)
        if self.plan.get_num_connections() > 0:
            self.publish_plan(state)

    def publish_plan(self, state):
        planned = self.controller.planned_states(state)
        self.plan.publish(path_msg(planned[:, :2], self.frame, rospy.Time.now(),
                                   headings=planned[:, 2]))


def single_threaded_blas() -> None:
    """Small matrices: BLAS threads only contend with other processes (10x slower under load)."""
    threadpool_limits(1)


def start() -> RewardControllerNode:
    """The node's start-up: ~parameters, the reward file (RewardFileError when missing or
    malformed), the controller, ROS wiring."""
    single_threaded_blas()
    config = read_config(RewardControllerParams)
    reward = load_reward(config.reward_file)
    saved = controller_settings(config.reward_file)
    config = config.with_reward_settings(saved)
    if saved and config.reward_settings:
        rospy.loginfo("driving with the controller settings saved with the reward: %s", saved)
    if isinstance(getattr(reward, "features", None), HallwayFeatures):
        rospy.loginfo("a hallway reward: path mode (path, scan, people, map)")
        return HallwayControllerNode(reward, config).setup()
    return RewardControllerNode(reward, config).setup()
