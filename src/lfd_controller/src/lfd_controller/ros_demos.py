"""Demonstrations as ROS messages, in bag files and in the database (ros_mongo)."""
import time
from pathlib import Path
from typing import TYPE_CHECKING, List, Optional, Sequence, Tuple

import numpy as np
import rosbag
import rospy

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError
from lfd_controller.msg import Demonstration as DemonstrationMsg

if TYPE_CHECKING:  # imported where the bags are read: the recorder node never needs the hallway
    from lfd_controller.hallway_recording import RecordedSensors  # model (and its SciPy imports)

DEMO_TOPIC = "/lfd/demonstrations"
REWARD_TOPIC = "/lfd/rewards"
# What the recorder keeps besides the steps in a building (its raw samples, bag topics).
SENSOR_TOPICS = ("/scan", "/people", "/path")


def to_msg(demo: Demonstration, stamp: Optional[rospy.Time] = None) -> DemonstrationMsg:
    msg = DemonstrationMsg()
    msg.header.stamp = stamp or rospy.Time.from_sec(time.time())
    msg.scenario_name, msg.scenario_yaml = demo.scenario.name, demo.scenario.to_yaml()
    msg.source, msg.dt, msg.t0 = demo.source, demo.scenario.dt, demo.t0
    msg.start = demo.start.tolist()
    states = demo.states if demo.states is not None else demo.rollout()
    msg.states = states.reshape(-1).tolist()
    msg.commands = demo.actions.reshape(-1).tolist()
    msg.times = (demo.t0 + demo.scenario.dt * np.arange(1, demo.length + 1)).tolist()
    msg.reached_goal = bool(demo.scenario.reached(states).any())
    msg.collided = bool(demo.scenario.collides(states, np.asarray(msg.times)).any())
    return msg


def from_msg(msg) -> Demonstration:
    commands = np.asarray(msg.commands, dtype=float)
    states = np.asarray(msg.states, dtype=float)
    if commands.size % 2 or states.size != commands.size // 2 * 5:
        raise DemonstrationError(f"demonstration message has {commands.size} command values and "
                                 f"{states.size} state values (need T x 2 and T x 5)")
    return Demonstration.from_dict({"scenario_yaml": msg.scenario_yaml, "start": list(msg.start),
                                    "actions": commands.reshape(-1, 2), "t0": msg.t0,
                                    "states": states.reshape(-1, 5), "source": msg.source})


def write_bag(path: Path, msg: DemonstrationMsg, raw: Sequence = ()) -> Path:
    """One demonstration per bag: the Demonstration on /lfd/demonstrations plus the raw
    (topic, message, stamp) samples it was built from. Refuses to overwrite."""
    path = Path(path)
    if path.exists():
        raise DemonstrationError(f"bag {path} exists already; not overwritten")
    path.parent.mkdir(parents=True, exist_ok=True)
    with rosbag.Bag(str(path), "w") as bag:
        for topic, message, stamp in raw:
            bag.write(topic, message, stamp)
        bag.write(DEMO_TOPIC, msg, msg.header.stamp)
    return path


def bag_files(paths: Sequence[Path]) -> List[Path]:
    """The bags named in `paths`: a folder stands for the *.bag files in it (sorted)."""
    files: List[Path] = []
    for path in map(Path, paths):
        files.extend(sorted(path.glob("*.bag")) if path.is_dir() else [path])
    return files


def read_bags(paths: Sequence[Path]) -> List[Demonstration]:
    """Demonstrations from bag files or folders of bags (sorted by name)."""
    demos = []
    for path in bag_files(paths):
        try:
            with rosbag.Bag(str(path)) as bag:
                demos.extend(from_msg(msg) for _, msg, _ in bag.read_messages(topics=[DEMO_TOPIC]))
        except (OSError, rosbag.ROSBagException) as err:
            raise DemonstrationError(f"cannot read bag {path}: {err}") from err
    return demos


def read_building_bags(paths: Sequence[Path]) -> List[Tuple[Demonstration, "RecordedSensors"]]:
    """(demonstration, what the robot saw) of each bag that holds a building drive (its path,
    scans and people: SENSOR_TOPICS); bags without a path are left out."""
    from lfd_controller.hallway_recording import RecordedSensors

    drives = []
    for path in bag_files(paths):
        try:
            with rosbag.Bag(str(path)) as bag:
                raw = {topic: [] for topic in SENSOR_TOPICS + ("/sim_time", "/odom", DEMO_TOPIC)}
                for topic, msg, stamp in bag.read_messages(topics=list(raw)):
                    raw[topic].append((msg, stamp))
        except (OSError, rosbag.ROSBagException) as err:
            raise DemonstrationError(f"cannot read bag {path}: {err}") from err
        if not raw["/path"] or not raw[DEMO_TOPIC]:
            continue
        demo = from_msg(raw[DEMO_TOPIC][0][0])
        clock = _episode_clock(raw, demo.t0)
        last_path = raw["/path"][-1][0]
        sensors = RecordedSensors(
            np.array([[p.pose.position.x, p.pose.position.y] for p in last_path.poses]),
            [(clock(m.header.stamp), *scan_arrays(m)) for m, _ in raw["/scan"]],
            [(clock(m.header.stamp), *people_arrays(m)) for m, _ in raw["/people"]])
        drives.append((demo, sensors))
    return drives


def _episode_clock(raw, t0: float):
    """stamp -> episode time: the simulator's /sim_time pairs (stamp, episode time); without
    them (a robot) the demonstration's t0 at its first recorded odometry stamp."""
    pairs = sorted((m.header.stamp.to_sec(), m.time_ref.to_sec()) for m, _ in raw["/sim_time"])
    if pairs:
        stamps, times = np.array(pairs).T

        def clock(stamp):       # from the nearest pair (before the first: the scan at the start)
            nearest = int(np.argmin(np.abs(stamps - stamp.to_sec())))
            return float(times[nearest] + stamp.to_sec() - stamps[nearest])
        return clock
    first = raw["/odom"][0][0].header.stamp.to_sec() if raw["/odom"] else 0.0
    return lambda stamp: t0 + stamp.to_sec() - first


def scan_arrays(msg) -> Tuple[np.ndarray, np.ndarray]:
    """(angles, ranges) of a sensor_msgs/LaserScan, readings outside its limits as inf."""
    angles = msg.angle_min + msg.angle_increment * np.arange(len(msg.ranges))
    ranges = np.asarray(msg.ranges, float)
    ranges[(ranges < msg.range_min) | (ranges > msg.range_max)] = np.inf
    return angles, ranges


def people_arrays(msg) -> Tuple[np.ndarray, np.ndarray]:
    """(positions (P, 2), velocities (P, 2)) of a robot_common/People."""
    return (np.array([[p.position.x, p.position.y] for p in msg.people]).reshape(-1, 2),
            np.array([[p.velocity.x, p.velocity.y] for p in msg.people]).reshape(-1, 2))


def store_demo(store, msg: DemonstrationMsg, *, session_id: Optional[str] = None) -> str:
    return store.insert_message(DEMO_TOPIC, msg, tags=["demonstration", msg.scenario_name, msg.source],
                                receive_time=msg.header.stamp.to_sec(), session_id=session_id)


def load_demos(store, *, scenario: Optional[str] = None, source: Optional[str] = None,
               session_id: Optional[str] = None, limit: Optional[int] = None) -> List[Demonstration]:
    """Stored demonstrations, oldest first, optionally of one scenario, source and session."""
    tags = ["demonstration"] + [tag for tag in (scenario, source) if tag]
    return [from_msg(stored.message())
            for stored in store.find_messages(topic=DEMO_TOPIC, tags=tags,
                                              session_id=session_id or None, limit=limit)]
