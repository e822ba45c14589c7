"""Learning from demonstration: a synthetic expert teleoperates through the joystick path, CIOC
learns its reward from the recorded demos, and the learned controller drives in the simulator."""
import threading
import time

import numpy as np
import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Joy, TimeReference
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from robot_common.ros_node import odom_state

TITLE = "Learning from demonstration: joystick demos -> CIOC reward -> controller (lfd_controller)"
DEMOS, STEPS, DRIVES = 5, 70, 2
LB, A, B = 4, 0, 1
# The lfd world runs beside the building robot of the other chapters: own namespace and frames.
NS = "/lfd"
FRAMES = {"ns": NS, "odom_frame": "lfd/odom", "base_frame": "lfd/base_link"}


class Watch:
    """Latest odometry / episode time / status of the simulator, and recorder events."""

    def __init__(self, on_step=None):
        self.lock, self.on_step = threading.Lock(), on_step
        self.state = self.time = None
        self.status, self.recording, self.trace = "", False, []
        self.subs = [rospy.Subscriber(NS + "/odom", Odometry, self._odom, queue_size=50),
                     rospy.Subscriber(NS + "/sim_time", TimeReference, self._time, queue_size=50),
                     rospy.Subscriber(NS + "/unicycle_sim/status", String, self._status, queue_size=5),
                     rospy.Subscriber(NS + "/demo_recorder/recording", Bool, self._recording, queue_size=5)]

    def _odom(self, msg):
        with self.lock:
            self.state = np.array(odom_state(msg))
            self.trace.append(self.state)
        if self.on_step is not None:
            self.on_step()

    def _time(self, msg):
        with self.lock:
            self.time = msg.time_ref.to_sec()

    def _status(self, msg):
        with self.lock:
            self.status = msg.data

    def _recording(self, msg):
        with self.lock:
            self.recording = msg.data

    def close(self):
        for sub in self.subs:
            sub.unregister()


def press(joy, button, axes=None):
    buttons = [0] * 11
    buttons[button] = 1
    joy.publish(Joy(axes=axes or [0.0] * 8, buttons=buttons))
    joy.publish(Joy(axes=[0.0] * 8, buttons=[0] * 11))


def wait(condition, timeout, what):
    from ros_harness import wait_until

    return wait_until(condition, timeout, what=what)


def new_episode(watch, reset):
    """Reset the simulator to a random start and wait until its first steps arrive."""
    with watch.lock:
        watch.time = None
    episode = reset().message.split()[1] + " "
    wait(lambda: watch.status.startswith(episode) and watch.time is not None and watch.time < 1.0,
         10, "the new episode")


def record_demos(demo, scenario, joy, watch, reset):
    from lfd_controller.expert import SyntheticExpert
    from lfd_controller.teleop import JoyMapping, JoyTeleop

    teleop = JoyTeleop(JoyMapping(scale_linear=0.9, scale_angular=3.0))
    expert = SyntheticExpert(steps=STEPS)
    queue = []

    def step():          # a teleoperator reacting to each simulator step
        if queue:
            buttons = [0] * 11
            buttons[LB] = 1
            joy.publish(Joy(axes=teleop.axes_for(*queue.pop(0)), buttons=buttons))
            if not queue:     # the plan is done: release LB and press B (stop recording)
                joy.publish(Joy(axes=[0.0] * 8, buttons=[0] * 11))
                press(joy, B)
    watch.on_step = step
    for k in range(DEMOS):
        new_episode(watch, reset)
        start, t0 = watch.state.copy(), watch.time
        plan = expert.plan(scenario, start, t0)
        press(joy, A)
        wait(lambda: watch.recording, 10, "recording to start")
        queue.extend(plan.tolist())
        step()       # the first command goes out now, so that the first recorded step applies it
        wait(lambda: not queue, 30, "the demonstration drive")
        wait(lambda: not watch.recording, 10, "recording to stop")
        print(f"  demo {k + 1}: from ({start[0]:.2f}, {start[1]:.2f}) {len(plan)} steps, "
              f"status {watch.status.split()[1]}", flush=True)
    watch.on_step = None


def drive(demo, scenario, watch, reset, reward_file):
    from robot_sim.scenarios import EpisodeResult

    controller = demo.launch("lfd_controller", "controller.launch", reward_file=str(reward_file),
                             scenario="static_obstacle", seed=9, time_scale=2.0, **FRAMES)
    controller.wait_for_topics([NS + "/reward_controller/cycle_time"], timeout=60)
    cycles = []
    sub = rospy.Subscriber(NS + "/reward_controller/cycle_time", rospy.AnyMsg,
                           lambda m: cycles.append(time.monotonic()), queue_size=50)
    results = []
    for _ in range(DRIVES):
        with watch.lock:
            watch.trace = []
        new_episode(watch, reset)
        wait(lambda: watch.status.split()[1] in ("reached", "collided"), 60, "the goal or a collision")
        with watch.lock:
            states = np.array(watch.trace)
        reached = watch.status.endswith("reached")
        times = np.arange(len(states)) * scenario.dt
        clearance = float((scenario.obstacle_distance(states, 0.0) - scenario.clearance).min())
        results.append(EpisodeResult(states, np.zeros((0, 2)), times, reached, not reached, clearance))
        print(f"  drive from ({states[0, 0]:.2f}, {states[0, 1]:.2f}): {watch.status.split()[1]} after "
              f"{times[-1]:.1f} s, closest {results[-1].min_clearance:.2f} m from touching the obstacle",
              flush=True)
    sub.unregister()
    span = cycles[-1] - cycles[0] if len(cycles) > 1 else 1.0
    print(f"  controller: {len(cycles) / span:.1f} Hz while driving", flush=True)
    return results


def run(demo) -> None:
    from lfd_controller.expert import true_reward
    from lfd_controller.learning import load_reward
    from lfd_controller.plots import plot_trajectories
    from lfd_controller.ros_learning import learn_from_sources
    from robot_sim.scenarios import load_scenario

    scenario = load_scenario("static_obstacle")
    out = demo.output / "lfd"
    session = f"demo_{time.strftime('%Y%m%d_%H%M%S')}"   # learn from this run's demos only
    # Recording runs in real time, as with a person at the joystick: the scripted teleoperator
    # answers each simulator step, and on a busy machine 2x left it too little time to keep up.
    launch = demo.launch("lfd_controller", "teleop_record.launch", scenario="static_obstacle", seed=5,
                         time_scale=1.0, bag_dir=str(out / "bags"), db_url=demo.db_url,
                         source="synthetic_expert", session_id=session, scale_linear=0.9,
                         scale_angular=3.0, **FRAMES)
    launch.wait_for_services([NS + "/demo_recorder/start", NS + "/unicycle_sim/reset"], timeout=60)
    launch.wait_for_subscribers([NS + "/joy"], timeout=30)
    joy = rospy.Publisher(NS + "/joy", Joy, queue_size=20)
    reset = rospy.ServiceProxy(NS + "/unicycle_sim/reset", Trigger)
    watch = Watch()
    wait(lambda: joy.get_num_connections() > 0 and watch.state is not None, 20, "teleop and simulator")
    print(f"  recording {DEMOS} demonstrations of {STEPS} steps through Joy -> joy_teleop -> "
          f"unicycle_sim -> demo_recorder (bags + CouchDB)", flush=True)
    record_demos(demo, scenario, joy, watch, reset)
    summary = learn_from_sources([], demo.db_url, scenario="static_obstacle", session_id=session,
                                 output=str(out / "reward.yaml"), plots=str(out))
    print("  " + summary.replace("\n", "\n  "), flush=True)
    learned, truth = load_reward(out / "reward.yaml").weights, true_reward().weights
    cosine = learned @ truth / np.linalg.norm(learned) / np.linalg.norm(truth)
    print(f"  cosine(learned, true weights) = {cosine:.3f}")
    demo.stop(launch)      # the recording set-up; the controller gets a fresh simulator at 2x
    watch.close()
    watch = Watch()
    results = drive(demo, scenario, watch, reset, out / "reward.yaml")
    path = plot_trajectories(results, scenario, out / "controller_trajectories.png", "learned controller")
    watch.close()
    print(f"  success {sum(r.success for r in results)}/{len(results)}; plot {path}")
    if not any(r.success for r in results):
        raise RuntimeError("the learned controller reached the goal in no drive")
