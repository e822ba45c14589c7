"""Making way for people who wait for the robot (no ROS).

People who meet a robot in a door or a narrow hall often stop and wait for it to move; a robot
that then waits for them, or backs up along their way, is in a waiting game nobody wins. A
person who walked up and stopped close in front of a held-up robot (`people_holding`) is taken
as waiting for it: the robot drives to the nearest spot out of the way of people coming along
its path and of where those waiting will walk on (toward the robot and past it, and the way
their track was walking: `ways_on`; detour.plan_give_way), waits there until the spot where it
was held is clear (or `WAIT` s), and then rejoins its path (the controller plans a detour back
to it). When someone comes up to it at its spot and waits there too, it was still in their
way: it moves on to another spot (`GivingWay.in_the_way`).
"""
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lfd_controller.hallway_features import near_people

__all__ = ["people_holding", "ways_on", "GivingWay", "GIVE_WAY_ROOMS"]

# A person standing (slower than STILL m/s) within HOLD_REACH m of the robot, in front of it,
# who was walking (at WALKING m/s or more) in the last seconds the caller keeps, holds it up:
# they stopped for the robot (people standing in a group all along do not wait for anybody).
# A tracked person (a name) walked when the same track did; an untracked one when someone
# walked within ARRIVED m of where they stand - which a passer-by beside a group also does.
# Giving way drives at SPEED m/s (turning in place first when the way on is more than TURN rad
# off), for at most DRIVE s, then waits up to WAIT s for the spot where the robot was held to
# clear (nobody within CLEAR m of it).
# Someone standing within CLEAR m of the robot MOVE_ON s after it got to its spot (which was
# CLEAR m from everybody) came up to it there and waits: it is still in their way, and moves
# on to another spot, at most MOVES times in one act of giving way.
# Who held the robot up and still stands where they stood (within HELD_AT m) holds it up
# however long ago they walked: a wait outlasts the walking the caller remembers.
HOLD_REACH, STILL, WALKING, ARRIVED, HELD_AT = 1.2, 0.2, 0.4, 1.0, 0.3
SPEED, TURN, DRIVE = 0.2, math.radians(60.0), 10.0
WAIT, CLEAR = 6.0, 1.0
MOVE_ON, MOVES = 2.0, 2
# The room a spot to give way at keeps, (m off the path's stretch round the robot, m off the
# waiting people and their ways on), tried in turn: where a door or a hall leaves no spot with
# the first, the second still lets them by (a person passes a standing robot at about 0.7 m,
# centre to centre) from closer to the path.
GIVE_WAY_ROOMS = ((0.8, CLEAR), (0.4, 0.75))


def people_holding(state, people, velocities, earlier=(), *, names=None,
                   reach: float = HOLD_REACH, held_by=()) -> np.ndarray:
    """Which of `people` (P, 2) stand within `reach` m in front of the robot at `state` (x, y,
    yaw, ...) and had walked up, by some earlier report in `earlier` ((people, velocities) or
    (people, velocities, names)): with a track name (`names`, people_msgs/Person.name; "" for
    an untracked detection) the same track was walking; without one, someone was walking within
    ARRIVED m of where they stand. Standing within HELD_AT m of one of `held_by` ((H, 2): where
    people stood who held the robot up before) counts as having walked up."""
    people = np.asarray(people, float).reshape(-1, 2)
    speeds = np.hypot(*np.asarray(velocities, float).reshape(-1, 2).T)
    offset = people - np.asarray(state[:2], float)
    ahead = offset @ np.array([math.cos(state[2]), math.sin(state[2])]) > 0.0
    names = list(names) if names is not None else [""] * len(people)
    walked = np.zeros(len(people), bool)
    for report in earlier:
        before, _, moving, tracks = _read(report)
        walking_names = {n for n, m in zip(tracks, moving) if m and n} if tracks else set()
        for i, name in enumerate(names):
            if name and tracks is not None:
                walked[i] |= name in walking_names
            else:
                walked[i] |= bool(np.any(np.hypot(*(before[moving] - people[i]).T) <= ARRIVED))
    held_by = np.asarray(held_by, float).reshape(-1, 2)
    if len(held_by) and len(people):
        walked |= near_people(people, held_by, HELD_AT)
    return (np.hypot(*offset.T) <= reach) & ahead & (speeds < STILL) & walked


def ways_on(people, earlier=(), *, names=None) -> np.ndarray:
    """Unit vectors (P, 2): the way each of `people` (P, 2) was last walking, by their track
    (`names`, in `earlier` as for people_holding); NaN where no track of theirs was seen
    walking."""
    ways = np.full((len(np.asarray(people, float).reshape(-1, 2)), 2), np.nan)
    names = list(names) if names is not None else [""] * len(ways)
    for report in earlier:       # oldest first: the latest walking report wins
        _, velocities, moving, tracks = _read(report)
        if not tracks:
            continue
        walking = {n: v / np.hypot(*v) for n, v, m in zip(tracks, velocities, moving) if n and m}
        for i, name in enumerate(names):
            if name in walking:
                ways[i] = walking[name]
    return ways


def _read(report):
    """One earlier report, (people, velocities) or (people, velocities, names): positions
    (P, 2), velocities (P, 2), who walked (speed WALKING m/s or more) and the track names (None
    when the tracker gave none)."""
    velocities = np.asarray(report[1], float).reshape(-1, 2)
    tracks = report[2] if len(report) > 2 and report[2] is not None else None
    return (np.asarray(report[0], float).reshape(-1, 2), velocities,
            np.hypot(*velocities.T) >= WALKING, tracks)


@dataclass
class GivingWay:
    """One act of giving way: `path` (N, 2) to the spot, `held_at` (x, y) where the robot was
    held up, from time `since`."""

    path: np.ndarray
    held_at: np.ndarray
    since: float
    arrived: Optional[float] = None
    moves: int = 0          # spots moved on to after the first

    def in_the_way(self, state, t: float, people, velocities) -> np.ndarray:
        """Which of `people` (P, 2) stand within CLEAR m of the robot at its spot MOVE_ON s
        after it got there (while it may still move on): it is still in their way."""
        people = np.asarray(people, float).reshape(-1, 2)
        if self.arrived is None or t - self.arrived < MOVE_ON or self.moves >= MOVES:
            return np.zeros(len(people), bool)
        speeds = np.hypot(*np.asarray(velocities, float).reshape(-1, 2).T)
        return (np.hypot(*(people - np.asarray(state[:2], float)).T) < CLEAR) & (speeds < STILL)

    def command(self, state, t: float, people) -> Optional[np.ndarray]:
        """The command this cycle: toward the spot (pure pursuit), then zero while waiting;
        None when done (the held spot is clear, or the time is up)."""
        position = np.asarray(state[:2], float)
        if self.arrived is None and (np.hypot(*(self.path[-1] - position)) < 0.15
                                     or t - self.since >= DRIVE):
            self.arrived = t
        if self.arrived is None:
            return self._toward(state)
        people = np.asarray(people, float).reshape(-1, 2)
        crowded = len(people) and np.hypot(*(people - self.held_at).T).min() < CLEAR
        if t - self.arrived >= WAIT or (t - self.arrived >= 1.0 and not crowded):
            return None
        return np.zeros(2)

    def _toward(self, state) -> np.ndarray:
        """Pure pursuit of the first path point 0.3 m or more away (the spot at the end)."""
        position = np.asarray(state[:2], float)
        distances = np.hypot(*(self.path - position).T)
        later = np.flatnonzero((np.arange(len(distances)) >= np.argmin(distances))
                               & (distances >= 0.3))
        target = self.path[later[0]] if len(later) else self.path[-1]
        bearing = math.remainder(math.atan2(target[1] - position[1], target[0] - position[0])
                                 - state[2], 2.0 * math.pi)
        turn = float(np.clip(2.0 * bearing, -1.0, 1.0))
        if abs(bearing) > TURN:
            return np.array([0.0, turn])
        return np.array([SPEED * math.cos(bearing), turn])
