"""Driving a planned path among simulated people (robot_sim.crowd), with known truth.

The people are `robot_sim.crowd.Crowd`'s: in each 0.5 m cell they arrive and leave so that the
cell holds Poisson(true density x area) people at any instant (robot_sim.people's densities at
that time of the week), each standing at a spot for an exponential time (20 s mean). People do
not walk into the robot: one who would appear on it stands just beside it instead.

The robot is a pure-pursuit follower at the controller's cruising speed: it steers toward the
path 1 m ahead of its place on it (nearer where the straight line would cut a corner), shifted
sideways (up to 0.5 m, where the hall is wide enough) to pass people standing in the way; it
slows down for anyone in its lane ahead and stops 0.15 m short, waiting until they leave or step
aside; within 0.5 m of anyone (edge to edge) it goes at most 0.3 m/s; where a step would bring
it within 0.01 m of a wall it steps back toward the path instead, or stops. Outcome: reached
(within 0.3 m of the goal in time: the path at 0.15 m/s plus 60 s), collisions (wall or
person), the distinct people who came within `meet_radius` of it (centre to centre) and the
time taken.
"""
import math
from dataclasses import dataclass

import numpy as np

from robot_common.gridplan import clearance_map
from robot_common.maps import GridMap
from robot_common.polylines import arc_lengths, points_along
from robot_sim.crowd import Crowd
from robot_sim.hallway import PERSON_RADIUS
from robot_sim.people import PeopleSimulator

ROBOT_RADIUS = 0.18
DT = 0.2
LOOK = 1.0            # m: pursuit point ahead on the path
SHIFTS = (0.0, 0.25, -0.25, 0.5, -0.5)
STOP_GAP = 0.15       # m: edge-to-edge gap kept to the person ahead
CLOSE_GAP, CLOSE_SPEED = 0.5, 0.3
TURN_RATE = 2.0       # rad/s
WALL_GAP = 0.01       # m: the least room to a wall the robot moves into (on the 0.1 m map)


@dataclass
class DriveOutcome:
    reached: bool
    collisions: int
    wall: bool            # the drive ended against a wall
    met: int
    seconds: float

    @property
    def success(self) -> bool:
        return self.reached and self.collisions == 0


class Floor:
    """A map prepared for driving: its clearance at 0.1 m (computed once)."""

    def __init__(self, grid: GridMap):
        factor = max(1, int(round(0.1 / grid.resolution)))
        self.fine = grid.downsample(factor)
        self.clear = clearance_map(self.fine, 1.0)

    def clearance_at(self, xy: np.ndarray) -> np.ndarray:
        row, col = self.fine.world_to_cell(xy[..., 0], xy[..., 1])
        inside = self.fine.inside(row, col)
        out = np.zeros(np.shape(row))
        out[inside] = self.clear[row[inside], col[inside]]
        return out


def drive(floor: Floor, sim: PeopleSimulator, points: np.ndarray, depart_hours: float, *,
          speed: float, meet_radius: float, seed: int) -> DriveOutcome:
    """Follow `points` (N, 2) leaving at `depart_hours` (of the week) among `sim`'s people."""
    arc = arc_lengths(points)
    dense = points_along(points, np.arange(0.0, arc[-1] + 0.1, 0.1), arc)
    crowd = Crowd(sim, radius=PERSON_RADIUS, seed=seed)
    pose = np.array(points[0], float)
    heading = math.atan2(*(dense[min(5, len(dense) - 1)] - pose)[::-1])
    progress, met, collisions, waited = 0, set(), 0, 0.0
    limit = time_limit(arc[-1])
    t = 0.0
    while t < limit:
        crowd.advance(t, depart_hours + t / 3600.0)
        step_aside(crowd, pose)
        near = np.hypot(*(crowd.xy - pose).T) if crowd.xy.size else np.zeros(0)
        met.update(crowd.names[near <= meet_radius].tolist())
        if np.hypot(*(pose - points[-1])) < 0.3:
            return DriveOutcome(True, collisions, False, len(met), t)
        window = dense[progress:progress + 30]
        progress += int(np.argmin(np.hypot(*(window - pose).T)))
        local = crowd.xy[near < 3.0]
        target = _target(floor, dense, progress, pose, local)
        wanted = math.atan2(target[1] - pose[1], target[0] - pose[0])
        turn = (wanted - heading + math.pi) % (2 * math.pi) - math.pi
        heading += max(-TURN_RATE * DT, min(TURN_RATE * DT, turn))
        step = _speed(pose, heading, local, speed) * max(0.0, math.cos(turn)) * DT
        waited = waited + DT if step < 0.01 else 0.0
        if waited > 1.0:
            make_way(crowd, pose, heading)
        moved = pose + step * np.array([math.cos(heading), math.sin(heading)])
        if step and floor.clearance_at(moved[None])[0] < ROBOT_RADIUS + WALL_GAP:
            back = dense[min(progress + 2, len(dense) - 1)] - pose   # too near a wall: back
            heading = math.atan2(back[1], back[0])                   # to the path, as it can
            moved = pose + back * min(1.0, step / max(float(np.hypot(*back)), 1e-9))
        if floor.clearance_at(moved[None])[0] >= ROBOT_RADIUS + WALL_GAP:  # else: a safety stop
            pose = moved
        t += DT
        if floor.clearance_at(pose[None])[0] < ROBOT_RADIUS:
            return DriveOutcome(False, collisions + 1, True, len(met), t)
        collisions += int(touching(pose, local))
    return DriveOutcome(False, collisions, False, len(met), t)


def step_aside(crowd: Crowd, pose: np.ndarray) -> None:
    """People who would stand on the robot stand just beside it."""
    if not crowd.xy.size:
        return
    offset = crowd.xy - pose
    gap = np.hypot(*offset.T)
    inside = gap < ROBOT_RADIUS + PERSON_RADIUS + 0.05
    if inside.any():
        direction = offset[inside] / np.maximum(gap[inside], 1e-6)[:, None]
        direction[gap[inside] < 1e-6] = (1.0, 0.0)
        crowd.xy[inside] = pose + direction * (ROBOT_RADIUS + PERSON_RADIUS + 0.06)


def touching(pose, people: np.ndarray) -> bool:
    """The robot at `pose` (x, y, ...) overlaps a person by more than 0.02 m."""
    return bool(people.size and np.hypot(*(people - np.asarray(pose)[:2]).T).min()
                < ROBOT_RADIUS + PERSON_RADIUS - 0.02)


def time_limit(length: float) -> float:
    """Seconds a drive of a `length` m path has, for every driver: the path at 0.15 m/s plus
    60 s (a drive still under way then counts as not reached)."""
    return length / 0.15 + 60.0


def make_way(crowd: Crowd, pose: np.ndarray, heading: float) -> None:
    """People standing in the robot's lane within 1 m ahead step sideways, away from it."""
    if not crowd.xy.size:
        return
    forward = np.array([math.cos(heading), math.sin(heading)])
    side = np.array([-forward[1], forward[0]])
    offset = crowd.xy - pose
    along, across = offset @ forward, offset @ side
    lane = (along > 0) & (along < 1.0 + ROBOT_RADIUS + PERSON_RADIUS) & \
        (np.abs(across) < ROBOT_RADIUS + PERSON_RADIUS + 0.05)
    away = np.where(across[lane] >= 0, 1.0, -1.0)
    crowd.xy[lane] += 0.5 * DT * away[:, None] * side


def _target(floor: Floor, dense, progress, pose, people) -> np.ndarray:
    """The pursuit point: the path up to LOOK ahead (nearer where the straight line to it
    would cut a corner), shifted sideways to pass people if need be."""
    for look in (LOOK, 0.6, 0.3, 0.1):
        ahead = min(progress + int(round(look / 0.1)), len(dense) - 1)
        if _line_clear(floor, pose, dense[ahead]):
            break
    point = dense[ahead]
    if ahead == len(dense) - 1 or not len(people):
        return point
    tangent = dense[ahead] - dense[max(ahead - 3, 0)]
    normal = np.array([-tangent[1], tangent[0]]) / max(np.hypot(*tangent), 1e-9)
    best, best_gap = point, -math.inf
    for shift in SHIFTS:
        candidate = point + shift * normal
        if shift and not _line_clear(floor, pose, candidate):
            continue
        gap = _segment_gap(pose, candidate, people)
        if gap >= STOP_GAP + 0.1:
            return candidate
        if gap > best_gap:
            best, best_gap = candidate, gap
    return best


def _line_clear(floor: Floor, a, b) -> bool:
    """The robot fits all along the straight line a -> b (with 0.07 m to spare)."""
    share = np.linspace(0.0, 1.0, 6)[:, None]
    return bool(floor.clearance_at(a + share * (b - a)).min() >= ROBOT_RADIUS + 0.07)


def _segment_gap(a, b, people) -> float:
    """Edge-to-edge distance from the robot moving a -> b to the nearest person."""
    d = b - a
    share = np.clip(((people - a) @ d) / max(float(d @ d), 1e-9), 0.0, 1.0)
    closest = a + share[:, None] * d
    return float(np.hypot(*(people - closest).T).min()) - ROBOT_RADIUS - PERSON_RADIUS


def _speed(pose, heading, people, cruise: float) -> float:
    if not len(people):
        return cruise
    offset = people - pose
    along = offset @ np.array([math.cos(heading), math.sin(heading)])
    across = np.abs(offset @ np.array([-math.sin(heading), math.cos(heading)]))
    lane = (along > 0) & (across < ROBOT_RADIUS + PERSON_RADIUS + 0.05)
    speed = cruise
    if lane.any():
        free = float(along[lane].min()) - ROBOT_RADIUS - PERSON_RADIUS - STOP_GAP
        speed = min(speed, max(0.0, free / 0.8 * cruise))
    if float(np.hypot(*offset.T).min()) - ROBOT_RADIUS - PERSON_RADIUS < CLOSE_GAP:
        speed = min(speed, CLOSE_SPEED)
    return speed
