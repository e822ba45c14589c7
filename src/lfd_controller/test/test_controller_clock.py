"""The reward controller without a simulator clock (no ROS master): episode time is wall-clock
seconds since driving was enabled (so the warm start shifts), the cycle budget is 1/rate, and the
optional collision barrier wraps the learned reward; plus the planner's budget and barrier cores."""
import time

import numpy as np
import pytest

from lfd_controller.errors import LfdError
from lfd_controller.expert import true_reward
from lfd_controller.features import Task
from lfd_controller.params import RewardControllerParams
from lfd_controller.planner import CollisionBarrier, RecedingHorizonController
from lfd_controller.ros_controller import RewardControllerNode
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
