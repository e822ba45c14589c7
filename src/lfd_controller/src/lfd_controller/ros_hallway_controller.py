"""HallwayControllerNode: reward_controller's path mode (a hallway reward file)."""
import threading
import time
from typing import Optional

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, SetBoolResponse

from lfd_controller.hallway import HALLWAY_DRIVING, HallwayController
from lfd_controller.params import RewardControllerParams
from lfd_controller.ros_demos import people_arrays, scan_arrays
from robot_common.gridplan import NoPathError, plan_path
from robot_common.msg import People
from robot_common.ros_maps import msg_to_grid
from robot_common.ros_node import odom_state
from robot_common.unicycle import Unicycle

__all__ = ["HallwayControllerNode"]

LEVELS = {"following": DiagnosticStatus.OK, "arrived": DiagnosticStatus.OK,
          "waiting": DiagnosticStatus.OK, "stopped": DiagnosticStatus.WARN,
          "backing up": DiagnosticStatus.WARN, "turning to the path": DiagnosticStatus.WARN,
          "giving way": DiagnosticStatus.WARN,
          "blocked": DiagnosticStatus.ERROR, "no path": DiagnosticStatus.WARN}


class HallwayControllerNode:
    """Follows a path through a building among people with a hallway reward (lfd_controller.
    hallway.HallwayController) at ~rate Hz.

    Parameters: RewardControllerParams (config/reward_controller.yaml): ~rate (cycle budget
      1/rate), ~max_iter, the limits, ~robot_radius, ~goal_tolerance, ~frame, ~enabled and the
      path mode's ~lookahead (4.0 m), ~safety_margin (0.05 m), ~blocked_after (20 s),
      ~replan_after (4 s: held up this long, a detour planned on the map and the scan),
      ~replan_ahead (2.5 m: with a map, that detour at once round something the map lacks on
      this much of the path ahead),
      ~give_way (true: held up by someone who stopped in front, first move out of their way),
      ~laser_offset (0.1 m), ~person_radius (0.25 m), ~barrier_margin (0.1 m: beyond touching
      a person), ~wall_margin (0.1 m: beyond touching a scan point).
    Topics in: odom (nav_msgs/Odometry, pose in the path's frame), path (nav_msgs/Path: the
      global plan, e.g. move_base's; followed from its first pose; one ending within
      ~goal_tolerance of the current goal is a re-plan, keeping the controller: along the same
      way it keeps the progress and blocked clocks too), goal (geometry_msgs/PoseStamped:
      planned on the map with robot_common.gridplan when no path comes; sent again, it retries
      a blocked path at once), map (nav_msgs/OccupancyGrid, latched), scan
      (sensor_msgs/LaserScan), people (robot_common/People: tracked positions, velocities and
      track names, the layout of people_msgs/People; a name tells giving way that the same
      person walked up and stopped).
    Topics out: cmd_vel (geometry_msgs/Twist), ~cycle_time (std_msgs/Float64), /diagnostics
      (diagnostic_msgs/DiagnosticArray, name "reward_controller: path"): OK following (progress,
      waypoint) / arrived, WARN stopped (zero speed, turning allowed: what the scan shows inside
      the margin on its way), backing up (held up again after a detour), turning to the path
      (in place, on a new path or after a detour or backing up, toward a waypoint behind it),
      giving way (to a spot out of the way, or waiting there, of someone who stopped for the
      robot) or no path, ERROR blocked (stood still ~blocked_after s, or no 0.3 m of progress
      for 3 x that, detours and backing up tried: the robot stays stopped until a path another
      way, a goal, or a re-plan once it has been blocked ~blocked_after s).
    Services: ~enable (std_srvs/SetBool).
    """

    def __init__(self, reward, config: RewardControllerParams):
        self.reward, self.config, self.lock = reward, config, threading.Lock()
        self.model = Unicycle(0.1, config.limits())
        self.settings = dict(HALLWAY_DRIVING, max_iter=config.max_iter)
        self.enabled = config.enabled
        self.controller: Optional[HallwayController] = None
        self.state = self.scan = self.grid = None
        self.people = (np.zeros((0, 2)), np.zeros((0, 2)), [])
        self.status = "no path"
        self.origin = time.monotonic()

    def setup(self) -> "HallwayControllerNode":
        self.cmd = rospy.Publisher("cmd_vel", Twist, queue_size=5)
        self.cycle = rospy.Publisher("~cycle_time", Float64, queue_size=10)
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)
        rospy.Subscriber("odom", Odometry, self.on_odom, queue_size=1)
        rospy.Subscriber("path", Path, self.on_path, queue_size=1)
        rospy.Subscriber("goal", PoseStamped, self.on_goal, queue_size=1)
        rospy.Subscriber("map", OccupancyGrid, self.on_map, queue_size=1)
        rospy.Subscriber("scan", LaserScan, self.on_scan, queue_size=1)
        rospy.Subscriber("people", People, self.on_people, queue_size=1)
        rospy.Service("~enable", SetBool, self.on_enable)
        self.timer = rospy.Timer(rospy.Duration(1.0 / self.config.rate), self.tick)
        return self

    def follow(self, points: np.ndarray, source: str, *, retry: bool = False) -> None:
        """Follow `points`: a re-plan to the goal being driven to keeps the controller (what it
        saw on its way, its recovery counts; HallwayController.new_path); another goal, or
        `retry` (a goal sent again) after a blocked path, starts a new one."""
        with self.lock:
            controller = self.controller
            ended = controller is None or controller.status_.startswith("arrived") or (
                retry and controller.status_.startswith("blocked"))
            if not ended and \
                    np.hypot(*(controller.path[-1] - points[-1])) <= self.config.goal_tolerance:
                same = controller.new_path(points)
                replan = "a re-plan along the same way: " if same else "a re-plan: "
            else:
                controller = self.controller = HallwayController(
                    self.reward, points, self.model, budget=1.0 / self.config.rate,
                    goal_tolerance=self.config.goal_tolerance,
                    laser_offset=self.config.laser_offset, settings=self.settings,
                    safety=self.config.hallway_safety(), grid=self.grid)
                replan, same = "", False
            self.source, self.status = source, controller.status_
        # move_base re-plans the same way every second or so: only a change of way is news
        log = rospy.logdebug if same else rospy.loginfo
        log(f"reward_controller: following {replan}{source} ({len(points)} poses, "
            f"{controller.follower.length:.1f} m)")

    def on_path(self, msg: Path) -> None:
        points = np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses])
        if len(points) < 1:
            rospy.logwarn("reward_controller: ignored an empty path")
            return
        self.follow(points, f"the path on {rospy.resolve_name('path')}")

    def on_goal(self, msg: PoseStamped) -> None:
        with self.lock:
            grid, state = self.grid, self.state
        goal = (msg.pose.position.x, msg.pose.position.y)
        if grid is None or state is None:
            rospy.logwarn("reward_controller: a goal needs the map and odometry to plan a path")
            return
        try:
            points = plan_path(grid, state[0][:2], goal, clearance=self.config.robot_radius + 0.1)
        except NoPathError as err:
            with self.lock:
                self.controller, self.status = None, f"no path: {err}"
            self.cmd.publish(Twist())
            return
        self.follow(points, f"a planned path to ({goal[0]:.1f}, {goal[1]:.1f})", retry=True)

    def on_map(self, msg: OccupancyGrid) -> None:
        grid = msg_to_grid(msg)
        with self.lock:
            self.grid = grid
            if self.controller is not None:     # the detours of the path followed now use it
                self.controller.grid = grid

    def on_odom(self, msg: Odometry) -> None:
        with self.lock:
            self.state = (np.array(odom_state(msg)), time.monotonic())

    def on_scan(self, msg: LaserScan) -> None:
        scan = scan_arrays(msg)
        with self.lock:
            self.scan = scan

    def on_people(self, msg: People) -> None:
        people = people_arrays(msg) + ([person.name for person in msg.people],)
        with self.lock:
            self.people = people

    def on_enable(self, request):
        with self.lock:
            self.enabled = bool(request.data)
        if not request.data:
            self.cmd.publish(Twist())
        return SetBoolResponse(True, "driving" if request.data else "stopped")

    def tick(self, _event) -> None:
        with self.lock:
            controller, state, scan, people = self.controller, self.state, self.scan, self.people
            enabled = self.enabled
        if not enabled or controller is None or state is None or scan is None:
            self.report(controller)
            return
        started = time.perf_counter()
        command = controller.act(state[0], time.monotonic() - self.origin, scan[0], scan[1],
                                 *people)
        self.cycle.publish(Float64(time.perf_counter() - started))
        twist = Twist()
        twist.linear.x, twist.angular.z = float(command[0]), float(command[1])
        self.cmd.publish(twist)
        with self.lock:
            self.status = controller.status_
        self.report(controller)

    def report(self, controller: Optional[HallwayController]) -> None:
        with self.lock:
            status, enabled, scan = self.status, self.enabled, self.scan
        message = status if enabled else "disabled"
        if enabled and controller is not None and scan is None:
            message = "waiting for scan"
        item = DiagnosticStatus(name="reward_controller: path", hardware_id="lfd_controller",
                                level=LEVELS.get(message.split(":")[0], DiagnosticStatus.OK),
                                message=message)
        if controller is not None:
            follower = controller.follower
            item.values = [KeyValue("following", self.source),
                           KeyValue("progress_m", f"{follower.progress:.2f}"),
                           KeyValue("length_m", f"{follower.length:.2f}"),
                           KeyValue("detours", str(controller.detours_)),
                           KeyValue("backing_up", str(controller.backups_)),
                           KeyValue("giving_way", str(controller.give_ways_))]
        array = DiagnosticArray(status=[item])
        array.header.stamp = rospy.Time.now()
        self.diagnostics.publish(array)
