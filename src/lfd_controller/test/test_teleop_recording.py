"""Pure cores of teleoperation and recording: axis mapping, dead-man button, button edges, building a
demonstration from steps, the controller core, and bad input."""
import numpy as np
import pytest

from lfd_controller.demos import Demonstration, trim_to_goal
from lfd_controller.errors import DemonstrationError, LfdError, RewardFileError
from lfd_controller.learning import load_reward, save_reward
from lfd_controller.recording import DemoBuilder, SampleMatcher
from lfd_controller.teleop import JoyMapping, JoyTeleop


def test_dead_man_button_deadzone_and_button_edges():
    teleop = JoyTeleop(JoyMapping(deadzone=0.1))
    idle, lb, lb_a = [0] * 11, [0, 0, 0, 0, 1] + [0] * 6, [1, 0, 0, 0, 1] + [0] * 6
    assert teleop.update([0.5, 1.0], idle) == (None, [])
    command, events = teleop.update([0.05, 1.0], lb_a)
    assert command == (pytest.approx(0.5), 0.0) and events == ["start"]
    assert teleop.update([0.0, 1.0], lb_a)[1] == []          # A still held: no new event
    assert teleop.update([0.0, 1.0], idle)[0] == (0.0, 0.0)  # release: one stop command
    assert teleop.update([0.0, 1.0], idle)[0] is None
    axes = teleop.axes_for(-0.2, 0.9)
    command, _ = teleop.update(axes, lb)
    assert command == (pytest.approx(-0.2), pytest.approx(0.9))
    with pytest.raises(LfdError, match="deadzone"):
        JoyMapping(deadzone=1.5)
    with pytest.raises(LfdError, match="enable_button"):
        JoyMapping(enable_button="LB")


def test_samples_join_by_stamp_and_build_a_model_consistent_demo(static_scenario):
    model = static_scenario.model()
    start = np.array([-2.4, 0.2, 0.0, 0.0, 0.0])
    actions = np.tile([0.4, 0.1], (12, 1))
    states = model.rollout(start, actions)
    matcher, builder = SampleMatcher(), DemoBuilder(min_steps=5)
    builder.observe(start, [0, 0], 0.0)
    builder.start()
    for k, (state, action) in enumerate(zip(states, actions)):
        parts = [("time", 0.1 * (k + 1)), ("state", state), ("command", action)]
        for part, value in (parts if k % 2 else parts[::-1]):
            step = matcher.add(k, part, value)
        builder.observe(step["state"], step["command"], step["time"])
    demo = builder.stop(static_scenario)
    np.testing.assert_allclose(demo.start, start)
    np.testing.assert_allclose(demo.actions, actions)
    assert demo.meta["model_error"] < 1e-12 and demo.t0 == 0.0
    assert Demonstration.from_dict(demo.to_dict()).actions.tolist() == demo.actions.tolist()
    with pytest.raises(DemonstrationError, match="not recording"):
        builder.stop(static_scenario)


def test_short_or_restarted_recordings_are_refused(static_scenario):
    builder = DemoBuilder(min_steps=5)
    builder.start()
    for k in range(3):
        builder.observe(np.zeros(5), [0, 0], 0.1 * k)
    with pytest.raises(DemonstrationError, match="too short"):
        builder.stop(static_scenario)
    builder.start()
    with pytest.raises(DemonstrationError, match="already recording"):
        builder.start()
    for k in range(8):
        builder.observe(np.zeros(5), [0, 0], 1.0 + 0.1 * k)
    builder.observe(np.zeros(5), [0, 0], 0.1)        # the simulator was reset: the drive ends
    assert not builder.recording and builder.stop(static_scenario).length == 8


def test_trim_to_goal_cuts_idling_after_arrival(static_scenario):
    start = np.array([-0.8, 0.0, 0.0, 0.0, 0.0])
    demo = Demonstration(static_scenario, start, np.tile([0.4, 0.0], (40, 1)))
    trimmed = trim_to_goal(demo, 2)
    assert trimmed.length < demo.length
    assert static_scenario.reached(trimmed.rollout()[-3])


def test_reward_files_round_trip_and_bad_files_are_refused(tmp_path):
    from lfd_controller.expert import true_reward

    path = save_reward(true_reward(), tmp_path / "r.yaml", note="test")
    assert load_reward(path).weights.tolist() == true_reward().weights.tolist()
    (tmp_path / "bad.yaml").write_text("kind: linear\nweights: {goal_distance: 1}\n")
    with pytest.raises(RewardFileError, match="misses weights"):
        load_reward(tmp_path / "bad.yaml")
    with pytest.raises(RewardFileError, match="cannot read"):
        load_reward(tmp_path / "none.yaml")
    with pytest.raises(RewardFileError, match="no reward file"):
        load_reward("")


def test_controller_core_reaches_the_goal_past_a_moving_obstacle():
    from lfd_controller.expert import true_reward
    from lfd_controller.features import Task
    from lfd_controller.planner import RecedingHorizonController
    from robot_sim.scenarios import load_scenario, run_episode

    scenario = load_scenario("moving_obstacle")
    controller = RecedingHorizonController(true_reward(), scenario.model())
    task = Task.from_scenario(scenario)
    result = run_episode(scenario, lambda x, t: controller.act(x, t, task), np.array([-2.5, -0.6, 0.2, 0, 0]))
    assert result.success and result.min_clearance > 0.05
    with pytest.raises(LfdError, match="horizon"):
        RecedingHorizonController(true_reward(), scenario.model(), horizon=1)
