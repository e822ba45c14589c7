"""Demonstrations as ROS messages, in bag files and in the database (ros_mongo)."""
import time
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np
import rosbag
import rospy

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError
from lfd_controller.msg import Demonstration as DemonstrationMsg

DEMO_TOPIC = "/lfd/demonstrations"
REWARD_TOPIC = "/lfd/rewards"


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


def read_bags(paths: Sequence[Path]) -> List[Demonstration]:
    """Demonstrations from bag files or folders of bags (sorted by name)."""
    files: List[Path] = []
    for path in map(Path, paths):
        files.extend(sorted(path.glob("*.bag")) if path.is_dir() else [path])
    demos = []
    for path in files:
        try:
            with rosbag.Bag(str(path)) as bag:
                demos.extend(from_msg(msg) for _, msg, _ in bag.read_messages(topics=[DEMO_TOPIC]))
        except (OSError, rosbag.ROSBagException) as err:
            raise DemonstrationError(f"cannot read bag {path}: {err}") from err
    return demos


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
