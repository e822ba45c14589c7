"""The reward controller without a simulator clock (no ROS master): episode time is wall-clock
seconds since driving was enabled (so the warm start shifts), the cycle budget is 1/rate, and the
optional collision barrier wraps the learned reward; plus the planner's budget and barrier cores."""
import time

import numpy as np
import pytest

from lfd_controller.errors import LfdError
from lfd_controller.expert import true_reward
from lfd_controller.features import Task, observed_acceleration
from lfd_controller.params import RewardControllerParams
from lfd_controller.planner import CollisionBarrier, RecedingHorizonController
from lfd_controller.ros_controller import RewardControllerNode
from robot_common.tasks import scenario_from_dict
from robot_common.unicycle import Unicycle


def test_without_sim_time_the_episode_time_is_wall_clock_since_enabled():
    config = RewardControllerParams.from_mapping({"reward_file": "r.yaml", "rate": 5.0,
                                                  "collision_margin": 0.1})
    node = RewardControllerNode(true_reward(), config)
    assert node.controller.budget == pytest.approx(0.2)
    assert isinstance(node.controller.reward, CollisionBarrier)
    node.goal = np.array([0.0, 0.0])
    seen = time.monotonic()
    node.obstacle = (np.array([-1.0, 0.0]), np.array([0.0, 0.5]), seen)
    node.clock_origin = seen - 5.0                # enabled five seconds before the obstacle was seen
    task, t = node.task_now()
    assert t >= 5.0
    # the obstacle at episode time t is where it was seen, moved on by its velocity since then
    now = node.clock_origin + t
    np.testing.assert_allclose(task.obstacle_position(np.array(t)), [-1.0, 0.5 * (now - seen)], atol=1e-9)
    later, t_later = node.task_now()
    assert t_later >= t                            # monotonic: the warm start shifts forward
    assert task.obstacle_spread is None             # nothing seen to change its velocity


def test_the_obstacle_topic_s_prediction_allows_for_the_changes_of_velocity_it_showed():
    config = RewardControllerParams.from_mapping({"reward_file": "r.yaml", "collision_margin": 0.1})
    node = RewardControllerNode(true_reward(), config)
    node.goal, now = np.array([0.0, 0.0]), time.monotonic()
    node.clock_origin = now - 5.0
    steady = [(now - 1.0 + 0.1 * k, np.array([0.0, 0.5])) for k in range(11)]
    node.obstacle_track.extend(steady)
    node.obstacle = (np.array([-1.0, 0.0]), np.array([0.0, 0.5]), now)
    task, t = node.task_now()
    assert task.obstacle_spread is None            # a steady walker: the prediction is exact
    # slowing down from 0.5 to 0.25 m/s in the last half second: 0.5 m/s^2
    node.obstacle_track.clear()
    node.obstacle_track.extend(steady[:6] + [(now - 0.5 + 0.1 * k, np.array([0.0, 0.5 - 0.05 * k]))
                                             for k in range(1, 6)])
    task, t = node.task_now()
    assert task.obstacle_spread(np.array([t + 1.0]))[0] == pytest.approx(0.25, abs=0.01)
    # and at least ~obstacle_accel however steady it looked
    config = RewardControllerParams.from_mapping({"reward_file": "r.yaml", "obstacle_accel": 1.0})
    node = RewardControllerNode(true_reward(), config)
    node.goal, node.clock_origin = np.array([0.0, 0.0]), now - 5.0
    node.obstacle_track.extend(steady)
    node.obstacle = (np.array([-1.0, 0.0]), np.array([0.0, 0.5]), now)
    task, t = node.task_now()
    assert task.obstacle_spread(np.array([t + 1.0]))[0] == pytest.approx(0.5, abs=0.01)


def test_the_obstacle_topic_is_remembered_for_its_changes_of_velocity_and_then_forgotten(
        monkeypatch):
    from nav_msgs.msg import Odometry

    from lfd_controller import ros_controller

    clock = [100.0]
    monkeypatch.setattr(ros_controller.time, "monotonic", lambda: clock[0])
    config = RewardControllerParams.from_mapping({"reward_file": "r.yaml", "collision_margin": 0.1})
    node = RewardControllerNode(true_reward(), config)
    node.goal, node.clock_origin = np.array([0.0, 0.0]), 90.0

    def seen(vy):
        msg = Odometry()
        msg.pose.pose.position.x, msg.twist.twist.linear.y = -1.0, vy
        node.on_obstacle(msg)
        clock[0] += 0.1
    for k in range(10):             # slowing from 0.5 to 0 m/s in a second: 0.5 m/s^2
        seen(0.5 - 0.05 * k)
    task, t = node.task_now()
    assert task.obstacle_spread(np.array([t + 1.0]))[0] == pytest.approx(0.25, abs=0.03)
    for _ in range(30):             # then standing for 3 s: the slowing is forgotten
        seen(0.0)
    assert node.obstacle_track[-1][0] - node.obstacle_track[0][0] <= 2.5 + 1e-9
    task, t = node.task_now()
    assert task.obstacle_spread is None


def test_an_obstacle_s_hardest_recent_change_of_velocity_is_measured_over_half_a_second():
    times = np.arange(0.0, 4.01, 0.1)
    # steady, then turning from +x to +y at 1 m/s within 0.5 s (around t = 1), then steady
    turned = times >= 1.0
    velocities = np.where(turned[:, None], [0.0, 1.0], [1.0, 0.0])
    assert observed_acceleration(times[:10], velocities[:10]) == 0.0
    assert observed_acceleration(times[:16], velocities[:16]) == pytest.approx(np.sqrt(2) / 0.5)
    # more than ACCEL_MEMORY s later it is forgotten
    assert observed_acceleration(times, velocities) == 0.0
    assert observed_acceleration([1.0], [[0.0, 1.0]]) == 0.0


def test_a_tracked_task_is_what_a_robot_s_node_sees_of_the_scenario_s_obstacle():
    # a walker at a steady 0.3 m/s: the constant-velocity prediction is exact, with no allowance
    walking = scenario_from_dict({"name": "walking", "goal": {"x": 0.0, "y": 0.0},
                                  "obstacle": {"x": -1.2, "y": -1.0, "radius": 0.25,
                                               "motion": {"kind": "linear", "velocity": [0.0, 0.3]}}})
    task = Task.tracked(walking, 3.0)
    ahead = np.array([3.0, 3.5, 5.0])
    np.testing.assert_allclose(task.obstacle_position(ahead), [[-1.2, -0.1], [-1.2, 0.05], [-1.2, 0.5]])
    assert task.obstacle_spread is None and task.obstacle_radius == 0.25
    # the node's floor on the allowance still applies: 0.3 m/s^2 x (1 s)^2 / 2 a second ahead
    assert Task.tracked(walking, 3.0, accel=0.3).obstacle_spread(np.array([4.0])) == pytest.approx([0.15])
    # an obstacle sweeping 0.8 m each way every 8 s: seen at its centre moving at full speed
    # (2 pi / 8 x 0.8 m/s), it keeps that velocity in the prediction
    sweeping = scenario_from_dict({"name": "sweeping", "goal": {"x": 0.0, "y": 0.0},
                                   "obstacle": {"x": -1.2, "y": 0.0, "radius": 0.25,
                                                "motion": {"kind": "oscillate", "amplitude": [0.0, 0.8],
                                                           "period": 8.0}}})
    peak = 2 * np.pi / 8.0 * 0.8
    task = Task.tracked(sweeping, 8.0)
    np.testing.assert_allclose(task.obstacle_position(np.array([8.0, 9.0])), [[-1.2, 0.0], [-1.2, peak]],
                               atol=1e-9)
    # it has been slowing and turning back: the allowance is for a change of velocity up to the
    # sweep's hardest (peak x 2 pi / 8 m/s^2) and more than half of it (the last 2.5 s at 10 Hz)
    hardest = peak * 2 * np.pi / 8.0
    spread = Task.tracked(sweeping, 8.0).obstacle_spread(np.array([9.0]))[0]
    assert 0.5 * 0.5 * hardest < spread <= 0.5 * hardest + 1e-9
    # before half a second of track the node has measured no change: no allowance
    assert Task.tracked(sweeping, 0.3).obstacle_spread is None


def test_the_warm_start_is_the_previous_plan_shifted_by_elapsed_time():
    controller = RecedingHorizonController(true_reward(), Unicycle(0.1), horizon=5, plan_dt=0.2)
    controller.plan_ = np.column_stack([np.arange(5.0), np.zeros(5)])
    controller._plan_time = 1.0
    np.testing.assert_allclose(controller._warm_start(1.2)[:, 0], [1, 2, 3, 4, 4])
    assert controller._warm_start(1.0 + 0.2 * 5) is None


def test_the_barrier_penalises_only_inside_the_margin_and_points_away():
    task = Task(np.zeros(2), lambda t: np.broadcast_to([1.0, 0.0], np.shape(t) + (2,)), 0.25)
    zero = true_reward(0.0)
    barrier = CollisionBarrier(zero, 0.43, margin=0.1, scale=100.0)
    states = np.array([[1.0 - 0.6, 0, 0, 0, 0], [1.0 - 0.48, 0, 0, 0, 0], [1.0, 0.6, 0, 0, 0]])
    rd = barrier.derivatives(states, np.zeros((3, 2)), np.zeros(3), task, order=1)
    assert rd.value[0] == 0.0 and rd.value[2] == 0.0          # 0.6 m away: outside 0.53 m
    assert rd.value[1] == pytest.approx(-100.0 * 0.5 ** 2)     # 0.05 m into the 0.1 m margin
    assert rd.rx[1, 0] < 0                                      # pushes away (to smaller x)
    with pytest.raises(LfdError, match="first derivatives"):
        barrier.derivatives(states, np.zeros((3, 2)), np.zeros(3), task, order=2)
    with pytest.raises(LfdError, match="cycle budget"):
        RecedingHorizonController(zero, Unicycle(0.1), budget=0.0)


def test_a_predicted_obstacle_s_barrier_widens_with_the_time_ahead_for_its_possible_error():
    zero = true_reward(0.0)
    barrier = CollisionBarrier(zero, 0.43, margin=0.1, scale=100.0)
    # still at (1, 0) seen at t = 2; it may speed up at 0.5 m/s^2
    exact = Task.constant_velocity(np.zeros(2), [1.0, 0.0], [0.0, 0.0], 2.0)
    unsure = Task.constant_velocity(np.zeros(2), [1.0, 0.0], [0.0, 0.0], 2.0, accel=0.5)
    states = np.tile([1.0 - 0.6, 0, 0, 0, 0], (4, 1))        # 0.6 m from it: outside 0.53 m
    times = np.array([2.0, 2.6, 3.0, 4.0])
    assert np.all(barrier.derivatives(states, np.zeros((4, 2)), times, exact, order=1).value == 0.0)
    value = barrier.derivatives(states, np.zeros((4, 2)), times, unsure, order=1).value
    assert value[0] == 0.0                                   # now: where it was seen
    # 0.6 s ahead it may be 0.09 m off: the robot is 0.02 m into the widened margin
    assert value[1] == pytest.approx(-100.0 * (0.02 / 0.1) ** 2)
    # the allowance stops growing after a second (0.25 m): planned again before then
    assert value[2] == pytest.approx(value[3]) and value[2] == pytest.approx(-100.0 * 1.8 ** 2)
