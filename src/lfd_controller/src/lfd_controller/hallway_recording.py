"""Hallway demonstrations from what the recorder kept of a drive in a building (no ROS).

A recorded building drive is a Demonstration (states and commands at the scenario's step) plus
what the robot saw meanwhile: the path it followed, its laser scans and the tracked people, each
with its episode time. `recorded_windows` gives each step the HallwayTask the controller would
have built from the newest scan and people report at that step (`hallway.TaskBuilder`, the
same local waypoint and scan points) and cuts the drive into 4 s windows (`hallway_windows`):
what `fit_hallway_reward` learns from.
"""
from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError
from lfd_controller.hallway import HALLWAY_SAFETY, HallwayDemonstration, TaskBuilder, hallway_windows

__all__ = ["RecordedSensors", "recorded_windows", "moving_speed"]

# A scan or people report counts at a step when it came at most this long (s, half a step)
# after it: the recorder's clock and the drive's steps are not in lockstep.
SEEN_SLACK = 0.05


@dataclass
class RecordedSensors:
    """What the robot saw during one recorded drive: `path` (N, 2) in the odometry frame;
    `scans` [(episode time, angles (B,) in the laser frame, ranges (B,))]; `people` [(episode
    time, positions (P, 2), velocities (P, 2))], each list oldest first."""

    path: np.ndarray
    scans: List[Tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    people: List[Tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    laser_offset: float = 0.0


def _newest(items: Sequence[Tuple], t: float, what: str):
    """The last item whose time is at most t (+ SEEN_SLACK)."""
    times = np.array([item[0] for item in items])
    index = int(np.searchsorted(times, t + SEEN_SLACK, side="right")) - 1
    if index < 0:
        raise DemonstrationError(f"no {what} at or before episode time {t:.2f} s")
    return items[index]


def recorded_windows(demo: Demonstration, sensors: RecordedSensors, *,
                     lookahead: float = HALLWAY_SAFETY["lookahead"]) -> List[HallwayDemonstration]:
    """The 4 s windows of a recorded building drive, each with the HallwayTask seen where it
    starts (DemonstrationError when the recording has no path or no scan)."""
    path = np.asarray(sensors.path, float).reshape(-1, 2)
    if len(path) < 2:
        raise DemonstrationError(f"a building demonstration needs the path it followed "
                                 f"(got {len(path)} poses)")
    if not sensors.scans:
        raise DemonstrationError("a building demonstration needs the laser scans of the drive")
    states = np.vstack([demo.start[None], demo.states if demo.states is not None else demo.rollout()])
    times = demo.t0 + np.arange(demo.length) * demo.scenario.dt
    # a recorder connects to each topic on its own: the first scan may come a step or two after
    # the drive starts; the steps before it (nothing seen yet) are left out
    first = int(np.searchsorted(times + SEEN_SLACK, sensors.scans[0][0]))
    if first >= demo.length:
        raise DemonstrationError(f"no laser scan within the drive's {demo.length * demo.scenario.dt:.1f} s "
                                 f"from episode time {demo.t0:.2f} s")
    builder = TaskBuilder(path, lookahead=lookahead, laser_offset=sensors.laser_offset)
    tasks = []
    no_people = (np.zeros((0, 2)), np.zeros((0, 2)))
    for k in range(first, demo.length):
        t = times[k]
        _, angles, ranges = _newest(sensors.scans, t, "laser scan")
        people = _newest(sensors.people, t, "people report")[1:] if sensors.people and \
            sensors.people[0][0] <= t + SEEN_SLACK else no_people
        tasks.append(builder(states[k], t, angles, ranges, people[0], people[1]))
    return hallway_windows(states[first:], demo.actions[first:], tasks, dt=demo.scenario.dt,
                           source=demo.source)


def moving_speed(demos: Sequence[Demonstration]) -> float:
    """The median speed (m/s) of the demonstrations' moving steps (above 0.05 m/s)."""
    speeds = np.concatenate([d.states[:, 3] if d.states is not None else d.rollout()[:, 3]
                             for d in demos])
    moving = speeds[speeds > 0.05]
    if not len(moving):
        raise DemonstrationError("the demonstrations never move")
    return float(np.median(moving))
