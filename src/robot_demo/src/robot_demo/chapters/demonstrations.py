"""Learning from demonstration: a simulated person (lfd_controller.sim: a reactive driver with a
reaction delay, a quantised stick and hand noise) drives through Joy -> joy_teleop -> unicycle_sim ->
demo_recorder; the person pipeline (learn_reward --kind person: CIOC + the controller-in-the-loop
acceptance check) learns from the recorded demos, and the learned controller drives in the
simulator."""
import threading
import time

import numpy as np
import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Joy, TimeReference
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from robot_common.ros_node import odom_state
from robot_demo import waits

TITLE = "Learning from demonstration: a person's joystick demos -> reward -> controller (lfd_controller)"
DEMOS, DRIVES = 6, 2
FAMILY = "tangent"            # the demonstrator family (lfd_controller.sim.FAMILIES)
SITTING = 8                   # odometry steps the person sits at the goal before recording stops
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
    from robot_demo.waits import wait_until

    return wait_until(condition, timeout, what)


def new_episode(watch, reset):
    """Reset the simulator to a random start and wait until its first steps arrive."""
    with watch.lock:
        watch.time = None
    episode = reset().message.split()[1] + " "
    wait(lambda: watch.status.startswith(episode) and watch.time is not None and watch.time < 1.0,
         30, "the new episode")


def record_demos(scenario, joy, watch, reset):
    """The person drives DEMOS times through Joy, one recording per drive (A starts, B stops)."""
    from lfd_controller.sim import Person, make_person

    person = Person(speed=0.4, delay=2, levels=5, noise=0.04, side=1.0, clearance=0.2,
                    overshoot=0.0, turn_gain=2.5)
    driver = make_person(FAMILY, 5, person=person)
    drive = {"active": False, "sitting": 0}

    def step():          # the person answers each odometry message with the stick they hold
        with watch.lock:
            state, t = watch.state, watch.time
        if not drive["active"] or state is None or t is None:
            return
        drive["sitting"] = drive["sitting"] + 1 if scenario.reached(state) else 0
        joy.publish(Joy(axes=driver.axes(state, t), buttons=driver.buttons()))
    print(f"  the person ({FAMILY} family): {driver.describe()}", flush=True)
    watch.on_step = step
    for k in range(DEMOS):
        new_episode(watch, reset)
        start = watch.state.copy()
        driver.reset(scenario)
        press(joy, A)
        wait(lambda: watch.recording, 30, "recording to start")
        drive.update(active=True, sitting=0)
        wait(lambda: drive["sitting"] >= SITTING or watch.status.split()[1] == "collided"
             or (watch.time or 0.0) > scenario.max_time, 120, "the demonstration drive")
        drive["active"] = False
        joy.publish(Joy(axes=[0.0] * 8, buttons=[0] * 11))      # let go of the stick
        press(joy, B)
        wait(lambda: not watch.recording, 30, "recording to stop")
        print(f"  demo {k + 1}: from ({start[0]:.2f}, {start[1]:.2f}), status {watch.status.split()[1]}",
              flush=True)
    watch.on_step = None


def drive(demo, scenario, watch, reset, reward_file):
    from robot_sim.scenarios import EpisodeResult

    controller = demo.launch("lfd_controller", "controller.launch", reward_file=str(reward_file),
                             scenario="static_obstacle", seed=9, time_scale=2.0, **FRAMES)
    waits.topics(controller, [NS + "/reward_controller/cycle_time"], 120)
    waits.services(controller, [NS + "/unicycle_sim/reset"], 120)     # the new simulator
    cycles = []
    sub = rospy.Subscriber(NS + "/reward_controller/cycle_time", rospy.AnyMsg,
                           lambda m: cycles.append(time.monotonic()), queue_size=50)
    results = []
    for _ in range(DRIVES):
        with watch.lock:
            watch.trace = []
        new_episode(watch, reset)
        wait(lambda: watch.status.split()[1] in ("reached", "collided"), 120, "the goal or a collision")
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
    from lfd_controller.learn_reward import learn_from_sources
    from lfd_controller.plots import plot_trajectories
    from lfd_controller.sim import PERSON_MAPPING
    from robot_sim.scenarios import load_scenario

    scenario = load_scenario("static_obstacle")
    out = demo.output / "lfd"
    session = f"demo_{time.strftime('%Y%m%d_%H%M%S')}"   # learn from this run's demos only
    # Recording runs in real time, as with a person at the joystick (the simulated person answers
    # each simulator step).
    launch = demo.launch("lfd_controller", "teleop_record.launch", scenario="static_obstacle", seed=5,
                         time_scale=1.0, bag_dir=str(out / "bags"), db_url=demo.db_url,
                         source=f"person:{FAMILY}", session_id=session,
                         scale_linear=PERSON_MAPPING.scale_linear,
                         scale_angular=PERSON_MAPPING.scale_angular, **FRAMES)
    waits.services(launch, [NS + "/demo_recorder/start", NS + "/unicycle_sim/reset"], 120)
    waits.subscribers(launch, [NS + "/joy"], 60)
    joy = rospy.Publisher(NS + "/joy", Joy, queue_size=20)
    reset = rospy.ServiceProxy(NS + "/unicycle_sim/reset", Trigger)
    watch = Watch()
    wait(lambda: joy.get_num_connections() > 0 and watch.state is not None, 60, "teleop and simulator")
    print(f"  recording {DEMOS} person-like demonstrations through Joy -> joy_teleop -> "
          f"unicycle_sim -> demo_recorder (bags + CouchDB)", flush=True)
    record_demos(scenario, joy, watch, reset)
    # the person pipeline; a reward whose controller does not drive like the person is still
    # saved here (accept_mismatch) so the chapter can show it, and the summary says so
    summary = learn_from_sources([], demo.db_url, scenario="static_obstacle", session_id=session,
                                 kind="person", output=str(out / "reward.yaml"), plots=str(out),
                                 trim_steps=0, accept_mismatch=True)
    print("  " + summary.replace("\n", "\n  "), flush=True)
    demo.stop(launch)      # the recording set-up; the controller gets a fresh simulator at 2x
    watch.close()
    watch = Watch()
    results = drive(demo, scenario, watch, reset, out / "reward.yaml")
    path = plot_trajectories(results, scenario, out / "controller_trajectories.png", "learned controller")
    watch.close()
    print(f"  success {sum(r.success for r in results)}/{len(results)}; plot {path}")
    if not any(r.success for r in results):
        raise RuntimeError("the learned controller reached the goal in no drive")
