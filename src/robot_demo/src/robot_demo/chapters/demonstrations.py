"""Learning from demonstration in a building: a simulated person (lfd_controller.sim's hallway
driver of the sampling_mpc family: a reaction delay, a quantised stick, hand noise) watches the
robot's scan and tracked people and drives a short hallway scene on the generated building floor
- from the main hall round the corner into the back hall, among people walking their rounds -
through Joy -> joy_teleop -> building_sim -> demo_recorder (bags with the path, scan and people;
the steps in CouchDB too). learn_reward --kind hallway learns a path-mode reward from exactly
this run's recorded bags, and reward_controller drives the same scene with it in a fresh
building_sim whose people walk other rounds. Both are checked against the simulator's truth:
the goal reached (odometry is the true pose), no collision (building_sim's status), the time
and the closest approach to the people (~people_truth: every person) beside the person's."""
import threading
import time
from types import SimpleNamespace

import numpy as np
import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import Joy, LaserScan, TimeReference
from std_msgs.msg import Bool, String

from robot_common.msg import People
from robot_common.ros_node import odom_state, path_msg
from robot_demo import waits

TITLE = ("Learning from demonstration in a building: a person's joystick drives among people -> "
         "hallway reward -> controller (lfd_controller)")
FAMILY = "sampling_mpc"       # the demonstrator family (lfd_controller.sim.FAMILIES)
DEMOS = 3                     # successful drives learned from (the person may fail one more)
TRIES = DEMOS + 1
PEOPLE = 3                    # people walking rounds through the halls
START = (18.0, 6.7, 0.0)      # the main hall, 7 m from its east end, facing east
GOAL = (26.2, 10.5)           # the back hall, round the corner (~11 m along the halls)
SEEDS = {"record": 0, "drive": 7}    # the simulators' people: the drive meets other rounds
RECORD_SCALE = 3.0            # the person drives at 3x real time (a stick per simulated step)
DT = 0.1                      # the simulator's step (simulator.launch): one odometry per step
TOLERANCE = 0.3               # the goal region's radius (robot_sim.hallway.HallwayScene)
SITTING = 8                   # steps the person sits at the goal before recording stops
A, B = 0, 1                   # the pad's record buttons (joy_teleop: start, stop)
# The lfd robot runs beside the building robot of the other chapters: own namespace and frames.
NS = "/lfd"
FRAMES = {"ns": NS, "odom_frame": "lfd/odom", "base_frame": "lfd/base_link",
          "laser_frame": "lfd/laser"}


class Watch:
    """The simulator's truth as it arrives: the robot's steps (odometry), its status, every
    person (~people_truth), and the scan and tracked people the robot sees. With a `clock`
    publisher it also publishes the simulator's episode time for the recorder (building_sim
    has no sim_time topic: one odometry message is one step of DT, stamped alike)."""

    def __init__(self, gap_to, clock=None):
        self.lock, self.on_step, self.gap_to, self.clock = threading.Lock(), None, gap_to, clock
        self.sim_steps = 0
        self.state, self.status, self.recording = None, "", False
        self.scan = self.people = None
        self.truth = np.zeros((0, 2))
        self.restart()
        topic = NS + "/building_sim/"
        self.subs = [rospy.Subscriber(NS + "/odom", Odometry, self._odom, queue_size=50),
                     rospy.Subscriber(NS + "/scan", LaserScan, self._store, "scan", queue_size=5),
                     rospy.Subscriber(NS + "/people", People, self._store, "people", queue_size=5),
                     rospy.Subscriber(topic + "people_truth", People, self._truth, queue_size=5),
                     rospy.Subscriber(topic + "status", String, self._store, "status", queue_size=5),
                     rospy.Subscriber(NS + "/demo_recorder/recording", Bool, self._store,
                                      "recording", queue_size=5)]

    def restart(self) -> None:
        """A new drive: no steps yet, nobody met, not arrived."""
        with self.lock:
            self.steps, self.track, self.closest, self.arrived = 0, [], np.inf, None

    def _odom(self, msg):
        state = np.array(odom_state(msg))
        with self.lock:
            self.state, self.steps, self.sim_steps = state, self.steps + 1, self.sim_steps + 1
            self.track.append(state[:2])
            if len(self.truth):
                self.closest = min(self.closest, float(self.gap_to(state, self.truth)))
            if self.arrived is None and np.hypot(*(state[:2] - GOAL)) <= TOLERANCE:
                self.arrived = self.steps
            sim_time = self.sim_steps * DT
        if self.clock is not None:     # the simulator's clock for the recorder: a step per odometry
            tick = TimeReference(time_ref=rospy.Time.from_sec(sim_time))
            tick.header.stamp = msg.header.stamp
            self.clock.publish(tick)
        if self.on_step is not None:
            self.on_step()

    def _truth(self, msg):
        where = np.array([[p.position.x, p.position.y] for p in msg.people]).reshape(-1, 2)
        with self.lock:
            self.truth = where

    def _store(self, msg, name):
        with self.lock:
            setattr(self, name, msg.data if name in ("status", "recording") else msg)

    @property
    def collided(self) -> bool:
        return self.status.startswith("collided")

    def close(self):
        for sub in self.subs:
            sub.unregister()


def press(joy, button):
    buttons = [0] * 11
    buttons[button] = 1
    joy.publish(Joy(axes=[0.0] * 8, buttons=buttons))
    joy.publish(Joy(axes=[0.0] * 8, buttons=[0] * 11))


def put_at_start(watch, initialpose) -> None:
    """The robot back at the start, standing (building_sim's initialpose; asked again while
    someone stands there and the simulator refuses)."""
    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = "map"
    pose.pose.pose.position.x, pose.pose.pose.position.y = START[:2]
    pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = np.sin(START[2] / 2), np.cos(START[2] / 2)
    asked = [0.0]

    def there():
        if time.monotonic() - asked[0] > 2.0:
            initialpose.publish(pose)
            asked[0] = time.monotonic()
        state = watch.state
        return (np.hypot(*(state[:2] - START[:2])) < 0.02 and abs(state[3]) < 1e-6
                and not watch.collided)
    waits.wait_until(there, 60, "the robot back at the start")


class Person:
    """The simulated person at the joystick: answers each simulator step with the stick they
    hold while driving (Joy -> joy_teleop), and presses A / B to start / stop a recording."""

    def __init__(self, joy, watch):
        from lfd_controller.sim.teach_hallway import family_person

        self.driver, self.joy, self.watch = family_person(FAMILY), joy, watch
        self.active, self.sitting = False, 0

    def step(self) -> None:
        from lfd_controller.ros_demos import people_arrays, scan_arrays

        watch = self.watch
        with watch.lock:
            state, steps, scan, people = watch.state, watch.steps, watch.scan, watch.people
        if not self.active or scan is None:
            return
        inside = np.hypot(*(state[:2] - GOAL)) <= TOLERANCE
        self.sitting = self.sitting + 1 if inside else 0
        angles, ranges = scan_arrays(scan)
        seen = people_arrays(people) if people is not None else (np.zeros((0, 2)),) * 2
        axes = self.driver.axes(state, steps * DT, SimpleNamespace(
            angles=angles, ranges=ranges, people=seen[0], velocities=seen[1]))
        self.joy.publish(Joy(axes=axes, buttons=self.driver.person.buttons()))

    def drive(self, scene, bag_dir):
        """One recorded drive from the start: (its bag, its figures)."""
        watch, limit = self.watch, int(scene.max_time / DT)
        before = set(bag_dir.glob("*.bag"))
        self.driver.reset(scene)
        press(self.joy, A)
        waits.wait_until(lambda: watch.recording, 30, "recording to start")
        watch.restart()
        self.active, self.sitting = True, 0
        waits.wait_until(lambda: self.sitting >= SITTING or watch.collided or watch.steps > limit,
                         limit * DT / RECORD_SCALE * 3, "the demonstration drive")
        self.active = False
        self.joy.publish(Joy(axes=[0.0] * 8, buttons=[0] * 11))      # let go of the stick
        press(self.joy, B)
        waits.wait_until(lambda: not watch.recording, 30, "recording to stop")
        new = waits.wait_until(lambda: set(bag_dir.glob("*.bag")) - before, 30, "the drive's bag")
        return sorted(new)[0], result(watch)


def record_demos(scene, joy, watch, initialpose, bag_dir):
    """The person drives the scene until DEMOS drives reached the goal (at most TRIES), one
    recording each; returns [(bag, figures)] of the successful drives."""
    person = Person(joy, watch)
    print(f"  the person ({FAMILY} family): {person.driver.person.describe()}", flush=True)
    watch.on_step = person.step
    kept = []
    for k in range(TRIES):
        if len(kept) == DEMOS:
            break
        put_at_start(watch, initialpose)
        bag, figures = person.drive(scene, bag_dir)
        print(f"  drive {k + 1}: {describe(figures)} -> {bag.name}", flush=True)
        if figures["success"]:
            kept.append((bag, figures))
    watch.on_step = None
    return kept


def result(watch) -> dict:
    """{success, collision, time (simulated s to the goal region), closest} of the last drive."""
    with watch.lock:
        arrived, status, closest = watch.arrived, watch.status, watch.closest
    collided = status.startswith("collided")
    return {"success": arrived is not None and not collided, "collision": status if collided else "",
            "time": arrived * DT if arrived is not None else float("nan"), "closest": closest}


def describe(figures) -> str:
    outcome = (f"collided ({figures['collision']})" if figures["collision"] else
               f"at the goal after {figures['time']:.1f} s" if figures["success"] else
               "did not reach the goal in the scene's time")
    return f"{outcome}, closest {figures['closest']:.2f} m from touching a person"


def drive_learned(demo, scene, reward_file):
    """reward_controller in path mode drives the scene in a fresh simulator (other people)."""
    watch = Watch(scene_gap(demo))
    launch = demo.launch("lfd_controller", "controller.launch", sim="building",
                         reward_file=str(reward_file), seed=SEEDS["drive"], people=PEOPLE,
                         start=f"[{START[0]}, {START[1]}, {START[2]}]", time_scale=1.0, **FRAMES)
    waits.subscribers(launch, [NS + "/path", NS + "/scan", NS + "/people"], 120)
    waits.wait_until(lambda: watch.state is not None and watch.scan is not None, 60,
                     "the new simulator's odometry and scan")
    cycles = []
    sub = rospy.Subscriber(NS + "/reward_controller/cycle_time", rospy.AnyMsg,
                           lambda m: cycles.append(time.monotonic()), queue_size=50)
    path = rospy.Publisher(NS + "/path", Path, queue_size=1, latch=True)
    limit = int(scene.max_time / DT)
    watch.restart()
    path.publish(path_msg(scene.path, FRAMES["odom_frame"]))
    waits.wait_until(lambda: watch.arrived is not None or watch.collided or watch.steps > limit,
                     limit * DT * 3, "the learned controller at the goal (or a collision)")
    figures = result(watch)
    sub.unregister()
    path.unregister()
    watch.close()
    span = cycles[-1] - cycles[0] if len(cycles) > 1 else 1.0
    print(f"  learned controller: {describe(figures)}; {len(cycles) / span:.1f} Hz while driving",
          flush=True)
    return figures


def scene_gap(demo):
    """gap(state, people (P, 2)): the robot's smallest edge-to-edge distance to a person."""
    from robot_sim.hallway import PERSON_RADIUS
    from robot_sim.params import BuildingSimParams

    room = demo.sim_config(BuildingSimParams, "building_sim.yaml").robot_radius + PERSON_RADIUS
    return lambda state, people: np.hypot(*(people - state[:2]).T).min() - room


def make_scene():
    """The scene the person drives: the generated building, the planner's path (as the
    controller plans one for a goal: 0.1 m more than the robot's radius from walls)."""
    from robot_common.gridplan import plan_path
    from robot_sim.building import generate_building
    from robot_sim.hallway import HallwayScene

    grid = generate_building(0).grid
    path = plan_path(grid, START[:2], GOAL, clearance=0.28)
    return HallwayScene(grid, path, np.array([*START, 0.0, 0.0]), [], goal_tolerance=TOLERANCE,
                        dt=DT, name="building")


def run(demo) -> None:
    scene = make_scene()
    session = f"building_{time.strftime('%Y%m%d_%H%M%S')}"   # this run's bags and database rows
    out = demo.output / "lfd"
    print(f"  the scene: generated building, ({START[0]:.0f}, {START[1]:.1f}) -> ({GOAL[0]:.1f}, "
          f"{GOAL[1]:.1f}), {scene.length:.1f} m along the halls, {PEOPLE} people walking rounds",
          flush=True)
    began = time.monotonic()
    kept = record(demo, scene, out / "bags" / session, session)
    print(f"  [recording: {time.monotonic() - began:.1f} s]", flush=True)
    if not kept:
        raise RuntimeError(f"the person reached the goal in none of {TRIES} drives")
    learn([bag for bag, _ in kept], out / "building_reward.yaml")
    began = time.monotonic()
    learned = drive_learned(demo, scene, out / "building_reward.yaml")
    print(f"  [driving: {time.monotonic() - began:.1f} s]", flush=True)
    compare([figures for _, figures in kept], learned)


def record(demo, scene, bag_dir, session):
    """The recording set-up (building_sim at RECORD_SCALE, joy_teleop, demo_recorder), the
    person's drives, and the set-up stopped; [(bag, figures)] of the successful drives."""
    from lfd_controller.hallway import hallway_scenario
    from lfd_controller.sim import PERSON_MAPPING

    bag_dir.mkdir(parents=True, exist_ok=True)
    launch = demo.launch("lfd_controller", "teleop_record.launch", sim="building",
                         seed=SEEDS["record"], people=PEOPLE, time_scale=RECORD_SCALE,
                         start=f"[{START[0]}, {START[1]}, {START[2]}]", bag_dir=str(bag_dir),
                         db_url=demo.db_url, source=f"person:{FAMILY}", session_id=session,
                         use_applied_cmd=True, scale_linear=PERSON_MAPPING.scale_linear,
                         scale_angular=PERSON_MAPPING.scale_angular, **FRAMES)
    waits.services(launch, [NS + "/demo_recorder/start"], 120)
    waits.subscribers(launch, [NS + "/joy", NS + "/initialpose", NS + "/path", NS + "/scenario",
                               NS + "/sim_time"], 60)
    joy = rospy.Publisher(NS + "/joy", Joy, queue_size=20)
    initialpose = rospy.Publisher(NS + "/initialpose", PoseWithCovarianceStamped, queue_size=1)
    latched = [rospy.Publisher(NS + "/path", Path, queue_size=1, latch=True),
               rospy.Publisher(NS + "/scenario", String, queue_size=1, latch=True)]
    latched[0].publish(path_msg(scene.path, FRAMES["odom_frame"]))
    latched[1].publish(String(data=hallway_scenario(DT, "building").to_yaml()))
    clock = rospy.Publisher(NS + "/sim_time", TimeReference, queue_size=50)
    watch = Watch(scene_gap(demo), clock)
    waits.wait_until(lambda: joy.get_num_connections() > 0 and initialpose.get_num_connections() > 0
                     and watch.state is not None and watch.scan is not None, 60,
                     "teleop and the simulator")
    print(f"  recording the person's drives through Joy -> joy_teleop -> building_sim "
          f"(x{RECORD_SCALE:.0f} real time) -> demo_recorder (bags + CouchDB, session {session})",
          flush=True)
    try:
        return record_demos(scene, joy, watch, initialpose, bag_dir)
    finally:
        watch.close()
        for publisher in latched + [joy, initialpose, clock]:
            publisher.unregister()
        demo.stop(launch)


def learn(bags, output) -> None:
    """learn_reward --kind hallway on exactly these bags."""
    from threadpoolctl import threadpool_limits

    from lfd_controller.learn_reward import learn_from_sources

    began, cpu = time.monotonic(), time.process_time()
    with threadpool_limits(1):       # small matrices: BLAS threads only contend
        summary = learn_from_sources([str(bag) for bag in bags], kind="hallway", output=str(output))
    print("  learn_reward --kind hallway (this run's bags): " + summary.replace("\n", "\n  ")
          + f"\n  [learning: {time.monotonic() - began:.1f} s, {time.process_time() - cpu:.1f} CPU-s]",
          flush=True)


def compare(person, learned) -> None:
    """The learned controller beside the person, checked (RuntimeError when it failed)."""
    times = [f["time"] for f in person]
    closest = min(f["closest"] for f in person)
    print(f"  the person: {len(person)} drives to the goal in {min(times):.1f}-{max(times):.1f} s, "
          f"closest {closest:.2f} m from touching a person", flush=True)
    if not learned["success"]:
        raise RuntimeError(f"the learned controller did not reach the goal: {describe(learned)}")
    print(f"  the learned controller: {learned['time']:.1f} s ({learned['time'] / np.mean(times):.2f}"
          f" x the person's mean), closest {learned['closest']:.2f} m from touching a person "
          f"(the person's closest {closest:.2f} m); no collision", flush=True)
