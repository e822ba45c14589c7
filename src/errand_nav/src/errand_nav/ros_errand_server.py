"""ErrandServer: move_base's action for a learned controller, with crowd-aware plans."""
import math
import threading
from typing import Optional, Tuple

import actionlib
import numpy as np
import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseFeedback, MoveBaseGoal, MoveBaseResult
from nav_msgs.msg import OccupancyGrid, Path
from nav_msgs.srv import GetPlan, GetPlanResponse
from sensor_msgs.msg import LaserScan
from std_srvs.srv import SetBool

from errand_nav.errand import Errand, at_hour_of_week, nearest_clear, remaining_path, with_obstacles
from errand_nav.forecast import DensityForecast
from errand_nav.params import ErrandServerParams
from errand_nav.planning import CrowdPlanner, PlannedPath
from errand_nav.ros_forecast import ask_forecast
from errand_nav.ros_places import PlaceGoals
from robot_common.gridplan import NoPathError
from robot_common.maps import beam_reach, load_map, seen_through, unmapped, yaw_to_quaternion
from robot_common.ros_maps import grid_to_msg, msg_to_grid
from robot_common.ros_node import path_msg, pose_2d, read_config

# Held up this long (s) without progress, the laser points the map lacks are kept: what the
# robot saw while held counts as in the way when the path is blocked.
HELD = 1.0
# A laser point within MAP_SLACK m of a wall of the map is that wall (robot_common.maps.unmapped).
MAP_SLACK = 0.15
# A point kept as in the way is forgotten once the beams by it all reach this far (m) past it
# (robot_common.maps.seen_through): a person standing there has left.
CLEAR_SLACK = 0.1

__all__ = ["ErrandServer", "start"]


def _moved(pose: Tuple[float, float, float], xy: np.ndarray) -> np.ndarray:
    """Points (N, 2) given in a frame whose pose in another is `pose` (x, y, yaw), in that
    other frame."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    xy = np.asarray(xy, float).reshape(-1, 2)
    return np.column_stack([x + c * xy[:, 0] - s * xy[:, 1], y + s * xy[:, 0] + c * xy[:, 1]])


def _set_pose(pose, x: float, y: float, yaw: float) -> None:
    """Fill a geometry_msgs/Pose from (x, y, yaw)."""
    pose.position.x, pose.position.y = float(x), float(y)
    (pose.orientation.x, pose.orientation.y, pose.orientation.z,
     pose.orientation.w) = yaw_to_quaternion(yaw)


class ErrandServer:
    """Serves move_base_msgs/MoveBaseAction on ~action_ns ("move_base") for a path-following
    controller (lfd_controller's reward_controller in path mode).

    A goal (geometry_msgs/PoseStamped, any frame tf can bring into ~map_frame) is planned on
    `map` with errand_nav.planning.CrowdPlanner: each cell costs the expected travel time through
    the people traffic_gp expects there when the robot would pass it (~density_service, asked
    for the times now .. now + the trip), plus ~person_cost s per person expected to be met.
    The plan goes out on ~plan (nav_msgs/Path, latched; each pose stamped with its expected
    pass time), which the controller follows. While driving: feedback (the robot's pose, from
    tf ~map_frame -> ~base_frame); held up for ~blocked_after s, the path is re-planned round
    what the laser (`scan`) shows the map lacks within ~obstacle_range, and what stood still
    there while the robot was held (the controller may have turned away from it by then), at
    most ~max_replans times; every ~replan_period s the crowd forecast is asked again and a
    plan better by ~switch_gain is taken. Result: succeeded within ~goal_tolerance of the
    goal; aborted with the reason (no path, blocked with no other path, no robot pose);
    preempted by a new goal or a cancel. Once a goal has ended (other than by a new goal) the
    controller is switched off through ~controller_enable (std_srvs/SetBool), as move_base
    stops commanding; a new goal switches it on.

    Also: ~make_plan (nav_msgs/GetPlan; start.header.stamp is the departure time, zero: now;
    an empty start frame: the robot's pose), ~go_to_place (errand_nav/GoToPlace: a phrase
    through region_search), move_base_simple/goal (rviz's 2D Nav Goal), /diagnostics
    ("errand_server": what it drives to, the plan's length, expected time and people met, and
    where the crowd forecast comes from)."""

    def __init__(self, config: ErrandServerParams):
        self.config, self.rules = config, config.rules()
        self.settings = config.planner_settings()
        self.lock = threading.Lock()
        self.planner: Optional[CrowdPlanner] = None
        self.scan: Optional[LaserScan] = None
        self.status, self.forecast_note = "waiting for a goal", "no forecast asked yet"
        self.current: Optional[PlannedPath] = None
        self.crowd_offset = 0.0       # crowd time - clock time (~plan_hour_of_week)

    def setup(self) -> "ErrandServer":
        if self.config.plan_hour_of_week >= 0:
            now = rospy.Time.now().to_sec()
            self.crowd_offset = at_hour_of_week(now, self.config.plan_hour_of_week) - now
        self.tf_buffer = tf2_ros.Buffer(rospy.Duration(30.0))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.plan_pub = rospy.Publisher("~plan", Path, queue_size=1, latch=True)
        self.path_pub = rospy.Publisher("path", Path, queue_size=1, latch=True)
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)
        if self.config.map_yaml:
            grid = load_map(self.config.map_yaml)
            self.map_pub = rospy.Publisher("map", OccupancyGrid, queue_size=1, latch=True)
            self.map_pub.publish(grid_to_msg(grid, self.config.map_frame, rospy.Time.now()))
            self.planner = CrowdPlanner(grid, self.settings)
        else:
            rospy.Subscriber("map", OccupancyGrid, self.on_map, queue_size=1)
        rospy.Subscriber("scan", LaserScan, self.on_scan, queue_size=1)
        rospy.Service("~make_plan", GetPlan, self.on_make_plan)
        self.server = actionlib.SimpleActionServer(self.config.action_ns, MoveBaseAction,
                                                   execute_cb=self.execute, auto_start=False)
        self.server.start()
        self.places = PlaceGoals(self.config, self.send_goal).setup()
        rospy.Subscriber("move_base_simple/goal", PoseStamped, self.send_goal, queue_size=1)
        self.client = actionlib.SimpleActionClient(self.config.action_ns, MoveBaseAction)
        rospy.Timer(rospy.Duration(1.0), lambda _event: self.report())
        return self

    # -- inputs ------------------------------------------------------------------------------
    def on_map(self, msg: OccupancyGrid) -> None:
        planner = CrowdPlanner(msg_to_grid(msg), self.settings)
        with self.lock:
            self.planner = planner
        rospy.loginfo(f"errand_server: map {msg.info.width} x {msg.info.height} cells "
                      f"at {msg.info.resolution:g} m")

    def on_scan(self, msg: LaserScan) -> None:
        with self.lock:
            self.scan = msg

    def send_goal(self, pose: PoseStamped) -> None:
        """Send `pose` to this node's own action (a new goal preempts the current one)."""
        self.client.wait_for_server(rospy.Duration(5.0))
        self.client.send_goal(MoveBaseGoal(target_pose=pose))

    # -- geometry ----------------------------------------------------------------------------
    def robot_pose(self, wait: float = 0.5) -> Optional[Tuple[float, float, float]]:
        try:
            return pose_2d(self.tf_buffer.lookup_transform(
                self.config.map_frame, self.config.base_frame, rospy.Time(0), rospy.Duration(wait)))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                tf2_ros.ExtrapolationException):
            return None

    def in_map(self, pose: PoseStamped) -> Tuple[float, float]:
        """(x, y) of a pose in ~map_frame (an empty frame means the map)."""
        frame = pose.header.frame_id.lstrip("/")
        if frame in ("", self.config.map_frame):
            return pose.pose.position.x, pose.pose.position.y
        frame_pose = pose_2d(self.tf_buffer.lookup_transform(
            self.config.map_frame, frame, rospy.Time(0), rospy.Duration(1.0)))
        x, y = _moved(frame_pose, [pose.pose.position.x, pose.pose.position.y])[0]
        return float(x), float(y)

    def latest_scan(self) -> Optional[Tuple[Tuple[float, float, float], np.ndarray, np.ndarray,
                                             np.ndarray]]:
        """The latest scan as (laser pose in the map frame, angles, returns - NaN where a beam
        has none -, reach: robot_common.maps.beam_reach), or None when there is none yet or its
        frame is not in tf."""
        with self.lock:
            scan = self.scan
        if scan is None:
            return None
        try:
            laser = pose_2d(self.tf_buffer.lookup_transform(
                self.config.map_frame, scan.header.frame_id, rospy.Time(0), rospy.Duration(0.5)))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                tf2_ros.ExtrapolationException):
            return None
        angles = scan.angle_min + scan.angle_increment * np.arange(len(scan.ranges))
        reach = beam_reach(scan.ranges, scan.range_min, scan.range_max)
        returned = (reach > 0.0) & (reach < scan.range_max)
        return laser, angles, np.where(returned, reach, np.nan), reach

    @staticmethod
    def scan_points(scan, near: Tuple[float, float], reach: float) -> np.ndarray:
        """The returns (map frame) of `scan` (latest_scan's tuple, or None) within `reach` m of
        `near`."""
        if scan is None:
            return np.zeros((0, 2))
        laser, angles, ranges, _ = scan
        ok = np.isfinite(ranges)
        points = _moved(laser, np.column_stack([ranges[ok] * np.cos(angles[ok]),
                                                ranges[ok] * np.sin(angles[ok])]))
        return points[np.hypot(points[:, 0] - near[0], points[:, 1] - near[1]) <= reach]

    @staticmethod
    def forget_seen_clear(errand: Errand, scan) -> None:
        """Forget the errand's kept obstacles that `scan` (latest_scan's tuple, or None) sees
        past."""
        if scan is None or not len(errand.obstacles):
            return
        laser, angles, _, reach = scan
        forgotten = errand.seen_clear(lambda points: seen_through(
            laser, angles, reach, points, CLEAR_SLACK))
        if forgotten:
            rospy.loginfo(f"errand_server: forgot {forgotten} laser points kept as in the way: "
                          f"the laser sees past them now ({len(errand.obstacles)} kept)")

    def unmapped_points(self, scan, grid, pose) -> np.ndarray:
        """The points of `scan` (latest_scan's tuple, or None) within obstacle_range of `pose`
        that `grid` lacks."""
        points = self.scan_points(scan, pose[:2], self.config.obstacle_range)
        return points[unmapped(grid, points, MAP_SLACK)]

    # -- planning ----------------------------------------------------------------------------
    def forecast(self, planner: CrowdPlanner, start, goal, departure: float) -> DensityForecast:
        """The crowd forecast for a trip from `start` to `goal` leaving at `departure` (s)."""
        if not self.config.density_service:
            self.forecast_note = "no crowd model configured: shortest travel time"
            return DensityForecast.quiet(planner.grid)
        trip = planner.plan(start, goal, departure, DensityForecast.quiet(planner.grid)).duration
        forecast, self.forecast_note = ask_forecast(self.config, departure, trip)
        return forecast if forecast is not None else DensityForecast.quiet(planner.grid)

    def plan(self, start, goal, departure: float, obstacles: np.ndarray = None) -> PlannedPath:
        with self.lock:
            planner = self.planner
        if planner is None:
            raise NoPathError("no map received on 'map' yet")
        if obstacles is not None and len(obstacles):
            planner = CrowdPlanner(with_obstacles(
                planner.grid, obstacles, self.config.obstacle_radius, keep_clear=start,
                keep_radius=self.settings.clearance + 0.05), self.settings)
        start = nearest_clear(planner.search, start, self.config.snap_radius)
        goal = nearest_clear(planner.search, goal, self.config.snap_radius)
        return planner.plan(start, goal, departure,
                            self.forecast(planner, start, goal, departure))

    def path_msg(self, planned: PlannedPath, frame: str = "",
                 frame_pose: Tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Path:
        """The plan as a nav_msgs/Path in the map frame, or in `frame` where the map frame's
        pose is `frame_pose` (x, y, yaw)."""
        return path_msg(_moved(frame_pose, planned.points), frame or self.config.map_frame,
                        rospy.Time.from_sec(float(planned.times[0])), headings="along",
                        stamps=[rospy.Time.from_sec(when) for when in planned.times])

    def publish_plan(self, planned: PlannedPath) -> None:
        """The plan on ~plan (map frame) and, for the controller, on `path` (controller_frame)."""
        msg = self.path_msg(planned)
        self.plan_pub.publish(msg)
        frame = self.config.controller_frame or self.config.map_frame
        if frame != self.config.map_frame:
            msg = self.path_msg(planned, frame, pose_2d(self.tf_buffer.lookup_transform(
                frame, self.config.map_frame, rospy.Time(0), rospy.Duration(1.0))))
        self.path_pub.publish(msg)

    def on_make_plan(self, request):
        departure = request.start.header.stamp.to_sec() or \
            rospy.Time.now().to_sec() + self.crowd_offset
        try:
            if request.start.header.frame_id:
                start = self.in_map(request.start)
            else:
                pose = self.robot_pose()
                if pose is None:
                    raise NoPathError("no start given and no robot pose on tf")
                start = pose[:2]
            planned = self.plan(start, self.in_map(request.goal), departure)
        except (NoPathError, tf2_ros.TransformException) as err:
            rospy.logwarn(f"errand_server: ~make_plan: {err}")
            return GetPlanResponse()
        rospy.loginfo(f"errand_server: ~make_plan: {self.describe(planned)}")
        return GetPlanResponse(plan=self.path_msg(planned))

    @staticmethod
    def describe(planned: PlannedPath) -> str:
        return (f"{planned.length:.1f} m, expected {planned.duration:.0f} s and "
                f"{planned.people_met:.1f} people met")

    # -- the action --------------------------------------------------------------------------
    def controller(self, drive: bool) -> None:
        """Switch the controller on or off (its ~enable service, when there is one)."""
        try:
            rospy.ServiceProxy(self.config.controller_enable, SetBool)(drive)
        except (rospy.ServiceException, rospy.ROSException):
            if not drive:
                pose = self.robot_pose()
                if pose is not None:       # a path that ends where the robot is: it stops
                    now = rospy.Time.now().to_sec()
                    here = PlannedPath(np.array([pose[:2]]), np.array([now]), 0.0, 0.0, 0.0, 0.0)
                    self.publish_plan(here)

    def finish(self, outcome: str, text: str) -> None:
        rospy.loginfo(f"errand_server: {outcome}: {text}")
        with self.lock:
            self.status, self.current = f"{outcome}: {text}", None
        if outcome != "replaced":       # like move_base: no command once a goal has ended
            self.controller(False)
        if outcome == "succeeded":
            self.server.set_succeeded(MoveBaseResult(), text)
        elif outcome == "aborted":
            self.server.set_aborted(MoveBaseResult(), text)
        else:
            self.server.set_preempted(MoveBaseResult(), text)
        self.report()

    def follow(self, errand: Errand, planned: PlannedPath, now: float, why: str) -> None:
        errand.follow(planned.points, now)
        with self.lock:
            self.current = planned
            self.status = f"driving to ({errand.goal[0]:.1f}, {errand.goal[1]:.1f}): {why}"
        try:
            self.publish_plan(planned)
        except tf2_ros.TransformException as err:
            rospy.logerr(f"errand_server: cannot give the controller its path: {err}")
        rospy.loginfo(f"errand_server: {why}: {self.describe(planned)}")
        self.report()

    def execute(self, goal: MoveBaseGoal) -> None:
        pose = self.robot_pose(wait=self.config.tf_timeout)
        if pose is None:
            return self.finish("aborted", f"no robot pose: no tf from {self.config.map_frame} "
                                          f"to {self.config.base_frame} within "
                                          f"{self.config.tf_timeout:g} s")
        now = rospy.Time.now().to_sec()
        try:
            target = self.in_map(goal.target_pose)
            planned = self.plan(pose[:2], target, now + self.crowd_offset)
            target = tuple(planned.points[-1])      # where it fits, within ~snap_radius
        except (NoPathError, tf2_ros.TransformException) as err:
            return self.finish("aborted", f"no path: {err}")
        errand = Errand(target, self.rules)
        self.controller(True)
        self.follow(errand, planned, now, "planned")
        rate = rospy.Rate(self.config.check_rate)
        while not rospy.is_shutdown():
            if self.server.is_preempt_requested():
                replaced = self.server.is_new_goal_available()
                return self.finish("replaced" if replaced else "preempted",
                                   "a new goal came" if replaced else "cancelled")
            pose = self.robot_pose()
            if pose is not None:
                self.publish_feedback(pose)
                outcome = self.step(errand, pose, rospy.Time.now().to_sec())
                if outcome is not None:
                    return self.finish(*outcome)
            rate.sleep()

    def step(self, errand: Errand, pose, now: float) -> Optional[Tuple[str, str]]:
        """One look at the errand; (outcome, text) when it ends."""
        verdict = errand.check(pose[:2], now)
        with self.lock:
            grid = self.planner.grid
        held = verdict.action == "go" and now - errand.last_progress >= HELD
        # one scan (one tf lookup) for the whole look, and none when nothing needs it
        scan = self.latest_scan() if (held or verdict.action == "blocked"
                                      or len(errand.obstacles)) else None
        self.forget_seen_clear(errand, scan)
        if held:
            errand.sighted(self.unmapped_points(scan, grid, pose))
        if verdict.action == "arrived":
            return "succeeded", f"reached the goal ({verdict.reason})"
        if verdict.action == "blocked":
            errand.replans += 1
            if errand.replans > self.rules.max_replans:
                return "aborted", (f"blocked: {verdict.reason}; gave up after "
                                   f"{self.rules.max_replans} new paths")
            before = len(errand.obstacles)
            seen = errand.saw_blocking(self.unmapped_points(scan, grid, pose))
            try:
                planned = self.plan(pose[:2], errand.goal, now + self.crowd_offset,
                                    obstacles=seen)
            except NoPathError as err:
                return "aborted", (f"blocked at ({pose[0]:.1f}, {pose[1]:.1f}): "
                                   f"{verdict.reason}; no other path: {err}")
            self.follow(errand, planned, now, f"re-planned at ({pose[0]:.1f}, {pose[1]:.1f}) "
                                              f"round {len(seen) - before} laser points the "
                                              f"map lacks, seen held up "
                                              f"({len(seen)} this errand; {verdict.reason})")
        elif verdict.action == "forecast":
            self.reconsider(errand, pose, now)
        return None

    def reconsider(self, errand: Errand, pose, now: float) -> None:
        """Take a new plan when the newer forecast makes it better by ~switch_gain."""
        errand.last_plan = now
        with self.lock:
            planner = self.planner
        try:
            departure = now + self.crowd_offset
            forecast = self.forecast(planner, pose[:2], errand.goal, departure)
            fresh = planner.plan(pose[:2], errand.goal, departure, forecast)
        except NoPathError:
            return
        kept = planner.evaluate(remaining_path(errand.path, pose[:2]), departure, forecast)
        if fresh.cost < (1.0 - self.config.switch_gain) * kept.cost:
            self.follow(errand, fresh, now, f"the crowd forecast changed: {fresh.cost:.0f} "
                                            f"against {kept.cost:.0f} s-equivalent")

    def publish_feedback(self, pose) -> None:
        feedback = MoveBaseFeedback()
        feedback.base_position.header.frame_id = self.config.map_frame
        feedback.base_position.header.stamp = rospy.Time.now()
        _set_pose(feedback.base_position.pose, *pose)
        self.server.publish_feedback(feedback)

    def report(self) -> None:
        with self.lock:
            status, current, ready = self.status, self.current, self.planner is not None
        level = DiagnosticStatus.OK
        if status.startswith("aborted") or not ready:
            level = DiagnosticStatus.WARN
        item = DiagnosticStatus(name="errand_server", hardware_id="errand_nav", level=level,
                                message=status if ready else "waiting for the map")
        item.values = [KeyValue("crowd forecast", self.forecast_note)]
        if current is not None:
            item.values += [KeyValue("length_m", f"{current.length:.1f}"),
                            KeyValue("expected_s", f"{current.duration:.0f}"),
                            KeyValue("expected_people_met", f"{current.people_met:.1f}")]
        array = DiagnosticArray(status=[item])
        array.header.stamp = rospy.Time.now()
        self.diagnostics.publish(array)


def start() -> ErrandServer:
    """The errand_server node: parameters read, the action served."""
    return ErrandServer(read_config(ErrandServerParams)).setup()
