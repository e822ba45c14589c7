"""The errand server for real, through move_base's action with a real actionlib client: a roscore,
launch/errands_sim.launch (robot_sim's building_sim driven by cmd_vel, lfd_controller's
reward_controller in path mode, errand_server), on a small floor of two corridors round a block
that holds a closed room. Reach, preempt, cancel, an unreachable goal, a blocked corridor
(re-planned round through the other one; aborted when both are blocked), and goals by phrase
through region_search's real nodes (a place it is sure of; two printers it cannot tell apart:
asked back with the candidates, nothing sent).

The robot drives with a hand-weighted hallway reward: these tests are about the action interface,
not about what was learned (bench/errand_nav and bench/lfd_controller measure that)."""
import math

import actionlib
import numpy as np
import pytest
import rospy
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PointStamped, PoseStamped, PoseWithCovarianceStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from nav_msgs.msg import Odometry, Path
from nav_msgs.srv import GetPlan
from std_srvs.srv import Trigger

from robot_common.maps import FREE, OCCUPIED, GridMap, save_map
from ros_harness import LaunchSet, wait_for_subscriber, wait_until

pytestmark = pytest.mark.ros

# The floor: 8 m x 5 m, a block from x 2 to 6 and y 1.5 to 3.5 between a south and a north
# corridor (1.5 m wide), a closed room inside the block.
START, SOUTH_EAST, NORTH_EAST = (1.0, 0.75), (7.0, 0.75), (7.0, 4.25)
ROOM = (4.0, 2.5)
DRIVE_TIMEOUT = 240.0
SIM = "/building_sim"        # the simulator node of launch/errands_sim.launch


def floor() -> GridMap:
    res = 0.1
    cells = np.full((50, 80), FREE, dtype=np.int8)
    cells[[0, -1], :], cells[:, [0, -1]] = OCCUPIED, OCCUPIED
    cells[15:35, 20:60] = OCCUPIED                        # the block
    cells[20:30, 33:47] = FREE                            # the closed room inside it
    return GridMap(cells, res)


def hallway_reward(path):
    from lfd_controller.hallway_features import HallwayFeatures
    from lfd_controller.learning import save_reward
    from lfd_controller.rewards import LinearReward
    features = HallwayFeatures()
    weights = dict.fromkeys(features.names, 0.0)
    weights.update(path_progress=12.0, speed_squared=-10.0, turn_squared=-1.0, speed_effort=-1.0,
                   turn_effort=-1.0, wall_proximity=-1.0, people_proximity=-5.0)
    return save_reward(LinearReward([weights[n] for n in features.names], features), path)


@pytest.fixture(scope="module")
def errands(roscore, rospy_node, tmp_path_factory, workspace_root):
    folder = tmp_path_factory.mktemp("errands")
    map_yaml = save_map(floor(), folder / "floor.yaml")
    reward = hallway_reward(folder / "hallway_reward.yaml")
    launches = LaunchSet(roscore, folder / "logs")
    launch = launches(str(workspace_root / "launch" / "errands_sim.launch"), map_yaml=str(map_yaml), people=0,
                      start=f"[{START[0]}, {START[1]}, 0.0]", reward_file=str(reward),
                      errand_params="{blocked_after: 6.0, replan_period: 30.0, min_confidence: 0.6}")
    launch.wait_for_services(["/errand_server/make_plan", "/errand_server/go_to_place",
                              "/building_sim/clear_obstacles"], timeout=120)
    client = actionlib.SimpleActionClient("/move_base", MoveBaseAction)
    assert client.wait_for_server(rospy.Duration(60)), "no move_base action server"
    robot = Robot(client)
    wait_until(lambda: robot.odom is not None, 60, what="odometry from building_sim")
    yield robot
    robot.close()       # the session's test node outlives this module: no subscriber left behind
    launches.stop_all()


class Robot:
    """The test's view: the action client, odometry, the latest plan, obstacle placement."""

    def __init__(self, client):
        self.client, self.odom, self.plan, self.track = client, None, None, []
        self.feedback = 0
        self.subscribers = [rospy.Subscriber("/odom", Odometry, self.on_odom, queue_size=10),
                            rospy.Subscriber("/errand_server/plan", Path, self.on_plan, queue_size=5)]
        self.obstacles = rospy.Publisher("/building_sim/obstacles_in", PointStamped, queue_size=20,
                                         latch=False)
        self.clear = rospy.ServiceProxy("/building_sim/clear_obstacles", Trigger)
        self.teleport = rospy.Publisher("/initialpose", PoseWithCovarianceStamped, queue_size=2)

    def close(self):
        for topic in self.subscribers + [self.obstacles, self.teleport]:
            topic.unregister()

    def put(self, xy):
        """Put the robot at `xy` (building_sim's initialpose), standing."""
        wait_for_subscriber(self.teleport, SIM, 60)
        pose = PoseWithCovarianceStamped()
        pose.header.frame_id, pose.header.stamp = "map", rospy.Time.now()
        pose.pose.pose.position.x, pose.pose.pose.position.y = xy
        pose.pose.pose.orientation.w = 1.0
        self.teleport.publish(pose)
        wait_until(lambda: self.distance(xy) < 0.05, 60, what=f"the robot put at {xy}")

    def on_odom(self, msg):
        self.odom = msg
        self.track.append((msg.pose.pose.position.x, msg.pose.pose.position.y))

    def on_plan(self, msg):
        self.plan = msg

    @property
    def xy(self):
        return self.odom.pose.pose.position.x, self.odom.pose.pose.position.y

    def goal(self, xy):
        goal = MoveBaseGoal()
        goal.target_pose.header.frame_id, goal.target_pose.header.stamp = "map", rospy.Time.now()
        goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = xy
        goal.target_pose.pose.orientation.w = 1.0
        return goal

    def send(self, xy):
        self.track = []
        self.client.send_goal(self.goal(xy), feedback_cb=self.on_feedback)

    def on_feedback(self, _feedback):
        self.feedback += 1

    def result(self, timeout=DRIVE_TIMEOUT):
        assert self.client.wait_for_result(rospy.Duration(timeout)), "no result in time"
        return self.client.get_state(), self.client.get_goal_status_text()

    def block(self, x, ys):
        wait_for_subscriber(self.obstacles, SIM, 60)
        for y in ys:
            point = PointStamped()
            point.header.frame_id, point.header.stamp = "map", rospy.Time.now()
            point.point.x, point.point.y = x, y
            self.obstacles.publish(point)

    def distance(self, xy):
        return math.hypot(self.xy[0] - xy[0], self.xy[1] - xy[1])


def test_a_goal_is_reached_with_feedback_and_a_published_plan(errands):
    errands.send(SOUTH_EAST)
    state, text = errands.result()
    assert state == GoalStatus.SUCCEEDED, text
    assert errands.distance(SOUTH_EAST) <= 0.35, errands.xy       # the server's 0.3 m, and odom
    assert errands.feedback > 0 and "reached the goal" in text
    ends = errands.plan.poses[0].pose.position, errands.plan.poses[-1].pose.position
    assert (ends[1].x, ends[1].y) == pytest.approx(SOUTH_EAST, abs=1e-6)
    assert max(y for _, y in errands.track) < 1.5                 # the south corridor: shortest


def test_the_plan_service_answers_without_driving(errands):
    make_plan = rospy.ServiceProxy("/errand_server/make_plan", GetPlan)
    start, goal = PoseStamped(), PoseStamped()
    start.header.frame_id = goal.header.frame_id = "map"
    start.pose.position.x, start.pose.position.y = START
    goal.pose.position.x, goal.pose.position.y = NORTH_EAST
    plan = make_plan(start=start, goal=goal, tolerance=0.0).plan
    xs = [p.pose.position.x for p in plan.poses]
    ys = [p.pose.position.y for p in plan.poses]
    assert (xs[0], ys[0]) == pytest.approx(START) and (xs[-1], ys[-1]) == pytest.approx(NORTH_EAST)
    assert max(ys) > 3.5                                          # through the north corridor
    stamps = [p.header.stamp.to_sec() for p in plan.poses]
    assert stamps == sorted(stamps) and stamps[-1] > stamps[0]    # expected pass times
    goal.pose.position.x, goal.pose.position.y = ROOM
    assert make_plan(start=start, goal=goal, tolerance=0.0).plan.poses == []


def test_an_unreachable_goal_is_aborted_with_the_reason(errands):
    errands.send(ROOM)
    state, text = errands.result(timeout=60)
    assert state == GoalStatus.ABORTED and text.startswith("no path"), text


def test_a_new_goal_preempts_and_a_cancel_stops_the_robot(errands):
    errands.put(START)
    other = actionlib.SimpleActionClient("/move_base", MoveBaseAction)   # another task executive
    assert other.wait_for_server(rospy.Duration(30))
    other.send_goal(errands.goal(NORTH_EAST))
    wait_until(lambda: errands.distance(START) > 0.5, 120, what="the robot on its way")
    errands.send(SOUTH_EAST)                                     # replaces the first goal
    assert other.wait_for_result(rospy.Duration(60))
    assert other.get_state() == GoalStatus.PREEMPTED
    assert other.get_goal_status_text() == "a new goal came"
    wait_until(lambda: errands.plan is not None and _ends_at(errands.plan, SOUTH_EAST), 60,
               what="a plan to the new goal")
    moved = errands.xy
    wait_until(lambda: errands.distance(moved) > 0.5, 120, what="the robot on its new way")
    errands.client.cancel_goal()
    state, text = errands.result(timeout=60)
    assert state == GoalStatus.PREEMPTED and text == "cancelled", text
    wait_until(lambda: abs(errands.odom.twist.twist.linear.x) < 0.02, 60,
               what="the robot standing after the cancel")
    stopped = errands.xy
    rospy.sleep(2.0)                 # then it stays: nothing drives it any more
    assert errands.distance(stopped) < 0.05


def test_a_blocked_corridor_is_replanned_round_and_aborted_when_no_way_is_left(errands):
    errands.clear()
    errands.put(START)
    errands.block(4.0, [0.25, 0.65, 1.05, 1.45])                 # across the south corridor
    errands.send(SOUTH_EAST)
    state, text = errands.result()
    assert state == GoalStatus.SUCCEEDED, text
    assert max(y for _, y in errands.track) > 3.5                # went round by the north
    errands.block(4.0, [3.55, 3.95, 4.35, 4.75])                 # and now the north one too
    errands.put((5.2, 0.75))                                     # just east of the south block
    errands.send(START)
    state, text = errands.result()
    assert state == GoalStatus.ABORTED and "no other path" in text, text
    assert errands.xy[0] > 4.0                                   # it never got past either
    errands.clear()


def _ends_at(plan, xy):
    end = plan.poses[-1].pose.position if plan.poses else None
    return end is not None and math.hypot(end.x - xy[0], end.y - xy[1]) < 1e-6


def write_vectors(path):
    """A hand-made word2vec space (axes: paper, drink, rest) whose answers are known."""
    words = {"print": 0, "printer": 0, "paper": 0, "poster": 0, "water": 1, "fountain": 1,
             "drink": 1, "drinking": 1, "thirsty": 1, "lounge": 2, "sofa": 2, "rest": 2}
    lines = [f"{len(words) + 1} 3"]
    for word, axis in words.items():
        vector = [0.05, 0.05, 0.05]
        vector[axis] = 1.0
        lines.append(word + " " + " ".join(f"{v:.3f}" for v in vector))
    lines.append("room 0.300 0.300 0.300")
    path.write_text("\n".join(lines) + "\n")


def test_a_goal_by_phrase_goes_where_region_search_is_sure_and_asks_back_where_not(
        errands, roslaunch, tmp_path):
    import json

    from errand_nav.srv import GoToPlace
    write_vectors(tmp_path / "vectors.txt")
    places = {"printer_north": NORTH_EAST, "printer_south": SOUTH_EAST,
              "water_fountain": (1.0, 4.25)}
    (tmp_path / "labels.json").write_text(json.dumps(
        {name: {"x": x, "y": y} for name, (x, y) in places.items()}))
    launch = roslaunch("region_search", "region_search.launch", backend="word2vec",
                       source="pretrained", pretrained_path=str(tmp_path / "vectors.txt"),
                       cache_dir=str(tmp_path / "cache"), remove_components=-1,
                       labels_path=str(tmp_path / "labels.json"), layer_service="")
    launch.wait_for_services(["/region_recommender/recommend"], timeout=90)
    wait_until(lambda: rospy.has_param("/embedding_server/active_backend"), 120,
               what="the embedding model to be ready")
    go = rospy.ServiceProxy("/errand_server/go_to_place", GoToPlace)
    sent = []
    rospy.Subscriber("/move_base/goal", rospy.AnyMsg, sent.append, queue_size=5)
    errands.put(START)
    looked = go(phrase="the water fountain", dry_run=True)
    assert looked.success and looked.label == "water_fountain", looked
    assert (looked.goal.pose.position.x, looked.goal.pose.position.y) == pytest.approx((1.0, 4.25))
    # Two printers: region_search's confidence in either is about 0.5, below the 0.6 this
    # errand server is set to drive at
    unsure = go(phrase="a printer", dry_run=False)
    assert not unsure.success and unsure.message.startswith("not sure"), unsure
    assert unsure.confidence < 0.6
    assert set(unsure.candidates[:2]) == {"printer_north", "printer_south"}, unsure
    assert "candidates: printer_" in unsure.message
    sure = go(phrase="where can I get a drink of water?", dry_run=False)
    assert sure.success and sure.label == "water_fountain" and sure.confidence >= 0.6, sure
    wait_until(lambda: len(sent) == 1, 30, what="the goal on the move_base action")
    wait_until(lambda: errands.plan is not None and _ends_at(errands.plan, (1.0, 4.25)), 60,
               what="a plan to the water fountain")
    errands.client.cancel_all_goals()
    assert len(sent) == 1                      # nothing was sent for the unsure phrase
