"""The acceptance check of a hallway reward learned from recorded building drives (no ROS).

A user's building is not in any simulator, so the check builds what it needs from each
recording itself (a Demonstration plus hallway_recording.RecordedSensors):

  * a static map of the drive (`recorded_map`): the recorded robot poses and each scan's
    returns, as a robot_common GridMap of 0.05 m cells over the area the drive saw. A cell is
    occupied where at least as many beams end in it as pass through it (a wall; a return
    within the person radius + 0.1 m of a tracked person is no wall), free where more beams
    pass through it, and UNKNOWN - not free - where no beam ever reached (what a person hid,
    what lies behind a wall): the simulated laser sees unknown cells as obstacles;
  * the people replayed from the tracked-people reports (`ReplayedPeople`): each report's
    people at its time, walking on at their tracked velocity until the next report (for at
    most REPORT_HOLD s; before the first report nobody). They do NOT react to the robot: a
    person who made way for the demonstrator walks the same way whatever the controller does,
    and someone who stepped aside for the person stands where they stood; touching one counts
    only where the robot drives into them (a replayed person walks on into a robot that is not
    where the recorded one was).
    Only people the recording tracked exist;
  * the person's own figures from the recording (`recorded_figures`: success = the drive ends
    within SUCCESS_TOLERANCE of the path's end without touching anything, as below; time to
    the goal; closest approach edge to edge to a replayed person) and the barrier margin from
    them (hallway.room_margin);
  * the controller's closed-loop drive (`controller_drive`): HallwayController with the node's
    settings (params.RewardControllerParams with the reward's barrier margin, no cycle budget:
    the verdict does not depend on how busy the machine is) from the demonstration's start
    along the recorded path, a Unicycle stepping it, scans ray-cast from the laser
    (`laser_offset` m ahead of the base) on the map plus the people's discs at the recording's
    beam angles, until it reaches the goal, touches something (an occupied cell's centre within
    the robot's radius - the returns lie within half a cell of it -, or a person's disc it
    drives into) or runs out of time: TIME_FACTOR x the person's time + TIME_EXTRA s;
  * the verdict (`check_recorded`): hallway.hallway_acceptance on the person's and the
    controller's figures (refused only where the controller fails where the person succeeded;
    refused too when no recorded drive succeeded: nothing was checked), with a line for each
    drive.

The check is conservative where the recording is silent (unknown space is solid) and blind to
what it never recorded (untracked people, doors opened later, people's answers to the robot).
"""
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.ndimage import distance_transform_edt
from threadpoolctl import threadpool_limits

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError
from lfd_controller.hallway import (
    HALLWAY_DRIVING,
    HALLWAY_SAFETY,
    HallwayController,
    hallway_acceptance,
    laser_pose,
    room_margin,
)
from lfd_controller.hallway_features import near_people
from lfd_controller.hallway_recording import RecordedSensors
from lfd_controller.params import RewardControllerParams
from robot_common.maps import FREE, OCCUPIED, UNKNOWN, GridMap, ray_disc_hits, raycast
from robot_common.unicycle import Unicycle

__all__ = ["CELL", "SUCCESS_TOLERANCE", "recorded_map", "ReplayedPeople", "RecordedWorld",
           "recorded_world", "recorded_figures", "controller_drive", "RecordedVerdict",
           "check_recorded"]

# The map: 0.05 m cells, beams up to REACH m (a return at or beyond it, or none, sees free to
# there: a simulated laser's and some drivers' "no return" is their range limit),
# one scan every MAP_EVERY s (the map is static: more scans add cost, not walls), PAD m round
# what the drive saw.
CELL, REACH, MAP_EVERY, PAD = 0.05, 8.0, 0.2, 0.5
# Returns this much (m) beyond a tracked person's radius are still that person (tracking error).
PERSON_SLACK = 0.1
# A report's people walk on at their velocity for at most this long (s); then nobody is tracked.
REPORT_HOLD = 1.0
# Arrived: within this distance (m) of the path's end (the simulated scenes' goal tolerance;
# the controller itself stops inside its own ~goal_tolerance, 0.25 m).
SUCCESS_TOLERANCE = 0.3
# The controller's time: 1.5 x the person's (hallway_acceptance refuses a median time over
# that anyway) + 20 s (one hold-up as long as ~blocked_after, resolved, still arrives).
TIME_FACTOR, TIME_EXTRA = 1.5, 20.0
# Touching a replayed person is the robot's doing when it closes in on them this fast (m/s) and
# faster than they close in on it.
CLOSING = 0.05
NOBODY = (np.zeros((0, 2)), np.zeros((0, 2)))


class ReplayedPeople:
    """The tracked people of a recording, replayed (module docstring): `at(t)` -> (positions
    (P, 2), velocities (P, 2))."""

    def __init__(self, reports: Sequence[Tuple[float, np.ndarray, np.ndarray]]):
        self.reports = list(reports)
        self.times = np.array([float(report[0]) for report in self.reports])

    def at(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        index = int(np.searchsorted(self.times, t + 1e-9, side="right")) - 1
        if index < 0 or t - self.times[index] > REPORT_HOLD:
            return NOBODY
        when, positions, velocities = self.reports[index]
        positions = np.asarray(positions, float).reshape(-1, 2)
        velocities = np.asarray(velocities, float).reshape(-1, 2)
        return positions + (t - when) * velocities, velocities


def _map_views(demo: Demonstration, sensors: RecordedSensors, people: ReplayedPeople,
               exclude: float, every: float):
    """(laser x, y, world angles (B,), ranges (B,), hit (B,)) of the scans the map uses: one
    every `every` s within the drive, each from the robot's recorded pose at its time; `hit`:
    a return that is no tracked person."""
    states, dt = demo.trajectory(), demo.scenario.dt
    last = -math.inf
    for when, angles, ranges in sensors.scans:
        step = int(round((when - demo.t0) / dt))
        if not -1 <= step <= len(states) or when - last < every:
            continue
        last = when
        lx, ly, yaw = laser_pose(states[min(max(step, 0), len(states) - 1)], sensors.laser_offset)
        world = yaw + np.asarray(angles, float)
        ranges = np.asarray(ranges, float)
        with np.errstate(invalid="ignore"):
            hit = np.isfinite(ranges) & (ranges > 0.01) & (ranges < REACH)
        ends = np.column_stack([lx + np.where(hit, ranges, 0) * np.cos(world),
                                ly + np.where(hit, ranges, 0) * np.sin(world)])
        positions, _ = people.at(when)
        if len(positions):
            hit &= ~near_people(ends, positions, exclude)
        reach = np.where(np.isnan(ranges), 0.0, np.minimum(ranges, REACH))   # inf: none to REACH
        yield lx, ly, world, reach, hit


def recorded_map(demo: Demonstration, sensors: RecordedSensors, *, cell: float = CELL,
                 person_radius: float = HALLWAY_SAFETY["person_radius"],
                 every: float = MAP_EVERY) -> GridMap:
    """The static map of one drive from its own scans (module docstring); DemonstrationError
    when no scan falls within the drive."""
    people = ReplayedPeople(sensors.people)
    views = list(_map_views(demo, sensors, people, person_radius + PERSON_SLACK, every))
    if not views:
        raise DemonstrationError(f"no laser scan within the drive's {demo.length * demo.scenario.dt:.1f} "
                                 f"s from episode time {demo.t0:.2f} s: the scans' times do not "
                                 "match the demonstration's")
    lasers = np.array([(lx, ly) for lx, ly, *_ in views])
    low, high = lasers.min(axis=0) - REACH - PAD, lasers.max(axis=0) + REACH + PAD
    shape = tuple(int(v) for v in np.ceil((high - low)[::-1] / cell))
    grid = GridMap(np.full(shape, UNKNOWN, np.int8), cell, (float(low[0]), float(low[1]), 0.0))
    hits, passes = np.zeros(grid.cells.size), np.zeros(grid.cells.size)
    samples = np.arange(0.5 * cell, REACH, cell)
    for lx, ly, world, ranges, hit in views:
        seen = samples[None] <= (ranges - np.where(hit, cell, 0.0))[:, None]
        along = np.broadcast_to(samples, seen.shape)[seen]
        beam = np.broadcast_to(np.arange(len(world))[:, None], seen.shape)[seen]
        passes += _cell_counts(grid, lx + along * np.cos(world[beam]),
                               ly + along * np.sin(world[beam]))
        hits += _cell_counts(grid, lx + ranges[hit] * np.cos(world[hit]),
                             ly + ranges[hit] * np.sin(world[hit]))
    cells = grid.cells.reshape(-1)
    cells[passes > 0] = FREE
    cells[(hits > 0) & (hits >= passes)] = OCCUPIED
    return grid


def _cell_counts(grid: GridMap, xs, ys) -> np.ndarray:
    """How many of the points (xs, ys) fall in each cell (flat, row-major)."""
    rows, cols = grid.world_to_cell(xs, ys)
    inside = grid.inside(rows, cols)
    return np.bincount(rows[inside] * grid.width + cols[inside], minlength=grid.cells.size)


@dataclass
class RecordedWorld:
    """One recorded drive as a world to drive in: its map, its replayed people, the robot's and
    a person's radius, the time step. `contact`, `person_gap` and `scan` answer as a simulator would."""

    grid: GridMap
    people: ReplayedPeople
    robot_radius: float = HALLWAY_SAFETY["robot_radius"]
    person_radius: float = HALLWAY_SAFETY["person_radius"]
    dt: float = 0.1
    _nearest: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        occupied = self.grid.cells == OCCUPIED
        self._nearest = None if not occupied.any() else \
            distance_transform_edt(~occupied, return_distances=False, return_indices=True)

    def wall_gap(self, state) -> float:
        """Distance (m) from the robot's centre to the centre of the nearest occupied cell (the
        returns that made it lie within half a cell of it; inf: none; outside the map: 0)."""
        if self._nearest is None:
            return math.inf
        row, col = self.grid.world_to_cell(float(state[0]), float(state[1]))
        if not self.grid.inside(row, col):
            return 0.0
        x, y = self.grid.cell_to_world(*self._nearest[:, row, col])
        return math.hypot(x - state[0], y - state[1])

    def person_gap(self, state, t: float) -> float:
        """Distance (m) between the robot's edge and the nearest replayed person's (inf: nobody)."""
        positions, _ = self.people.at(t)
        if not len(positions):
            return math.inf
        centre = float(np.hypot(*(positions - np.asarray(state[:2], float)).T).min())
        return centre - self.robot_radius - self.person_radius

    def contact(self, state, t: float) -> Optional[str]:
        """"wall" (an occupied cell's centre within the robot's radius), "person" or None: what
        the robot at `state` touches. A replayed person counts only when the robot drives into
        them: its last step (dt at its speed) brought it onto them, closing in at over CLOSING
        m/s and faster than they close in on it (replayed people walk on into a robot that is
        not where the recorded one was, where real people would have waited or stepped round
        it)."""
        if self.wall_gap(state) < self.robot_radius:
            return "wall"
        positions, velocities = self.people.at(t)
        reach = self.robot_radius + self.person_radius
        heading = np.array([math.cos(state[2]), math.sin(state[2])])
        offsets = positions - np.asarray(state[:2], float)
        distances = np.hypot(*offsets.T)
        before = np.hypot(*(offsets + self.dt * float(state[3]) * heading).T)
        new = (distances < reach) & (before >= reach)
        if not new.any():
            return None
        toward = offsets[new] / np.maximum(distances[new], 1e-9)[:, None]
        robot = toward @ (float(state[3]) * heading)
        person = -np.sum(toward * velocities[new], axis=1)
        return "person" if np.any((robot > CLOSING) & (robot >= person)) else None

    def scan(self, state, t: float, angles, laser_offset: float) -> np.ndarray:
        """Ranges at laser-frame `angles` from a laser `laser_offset` m ahead of the base at
        `state`: the map (unknown cells stop a beam) and the replayed people's discs."""
        lx, ly, yaw = laser_pose(state, laser_offset)
        world = yaw + np.asarray(angles, float)
        ranges = raycast(self.grid, lx, ly, world, REACH)
        positions, _ = self.people.at(t)
        if len(positions):
            entry, _ = ray_disc_hits(lx, ly, world, positions, self.person_radius)
            ranges = np.minimum(ranges, np.maximum(entry, 0.0))
        return ranges


def recorded_world(demo: Demonstration, sensors: RecordedSensors, **radii) -> RecordedWorld:
    """The world of one recorded drive (its map and people); DemonstrationError for a recording
    without the path, the scans (within the drive) or the states the check needs."""
    if len(np.asarray(sensors.path, float).reshape(-1, 2)) < 2:
        raise DemonstrationError("the recording has no path to follow (fewer than 2 poses)")
    if not np.all(np.isfinite(demo.trajectory())):
        raise DemonstrationError("the demonstration's recorded states are not all finite")
    person_radius = radii.get("person_radius", HALLWAY_SAFETY["person_radius"])
    return RecordedWorld(recorded_map(demo, sensors, person_radius=person_radius),
                         ReplayedPeople(sensors.people), dt=demo.scenario.dt, **radii)


def recorded_figures(states, t0: float, dt: float, world: RecordedWorld, goal,
                     tolerance: float = SUCCESS_TOLERANCE) -> Dict:
    """{success, collision, time, closest} of a drive x_0..x_T (every dt s from episode time t0)
    in `world`: success = it ends within `tolerance` of `goal` and touches nothing; time to the
    first arrival (nan: failed); closest: the smallest edge-to-edge gap to a person up to then
    (inf: nobody near)."""
    states = np.asarray(states, float)
    times = t0 + dt * np.arange(len(states))
    contacts = [world.contact(s, t) for s, t in zip(states, times)]
    collision = next((c for c in contacts if c is not None), None)
    near = np.hypot(*(states[:, :2] - np.asarray(goal, float)).T) < tolerance
    end = int(np.argmax(near)) if near.any() else len(states) - 1
    success = bool(near[-1]) and collision is None
    gaps = [world.person_gap(s, t) for s, t in zip(states[:end + 1], times[:end + 1])]
    return {"success": success, "collision": collision,
            "time": end * dt if success else float("nan"), "closest": float(min(gaps))}


def controller_drive(reward, demo: Demonstration, sensors: RecordedSensors,
                     world: RecordedWorld, *, config: RewardControllerParams,
                     time_limit: float, tolerance: float = SUCCESS_TOLERANCE) -> Dict:
    """recorded_figures of HallwayController (the node's settings in `config`, no cycle budget)
    driving `reward` from the demonstration's start along the recorded path in `world` for at
    most `time_limit` s, plus its last `status` and `cpu` seconds."""
    started, dt = time.process_time(), demo.scenario.dt
    model = Unicycle(dt, config.limits())
    path = np.asarray(sensors.path, float).reshape(-1, 2)
    controller = HallwayController(reward, path, model, budget=None,
                                   goal_tolerance=config.goal_tolerance,
                                   laser_offset=sensors.laser_offset,
                                   settings=dict(HALLWAY_DRIVING, max_iter=config.max_iter),
                                   safety=config.hallway_safety(), grid=world.grid)
    angles = np.asarray(sensors.scans[0][1], float)
    state, states = np.asarray(demo.start, float), [np.asarray(demo.start, float)]
    for k in range(int(round(time_limit / dt))):
        t = demo.t0 + k * dt
        positions, velocities = world.people.at(t)
        ranges = world.scan(state, t, angles, sensors.laser_offset)
        state = model.step(state, controller.act(state, t, angles, ranges, positions, velocities))
        states.append(state)
        if (world.contact(state, t + dt) is not None
                or math.hypot(*(state[:2] - path[-1])) < tolerance):
            break
    figures = recorded_figures(np.array(states), demo.t0, dt, world, path[-1], tolerance)
    figures.update(status=controller.status_, cpu=time.process_time() - started)
    return figures


@dataclass
class RecordedVerdict:
    """check_recorded's report: the verdict (hallway_acceptance), the barrier margin, the
    person's and the controller's figures and a line per drive. `failure_lines` and `describe`
    are what learning.RewardNotAcceptedError reads."""

    verdict: Dict
    margin: float
    names: List[str]
    person: List[Dict]
    controller: List[Dict]

    @property
    def accepted(self) -> bool:
        return bool(self.verdict["accepted"])

    def drive_lines(self) -> List[str]:
        return [f"{name}: person {_outcome(p)}, controller {_outcome(c)}"
                for name, p, c in zip(self.names, self.person, self.controller)]

    def failing_drives(self) -> List[str]:
        """The drives where the controller touched something, or failed or took over
        TIME_FACTOR x the person's time where the person succeeded."""
        return [name for name, p, c in zip(self.names, self.person, self.controller)
                if c["collision"] or (p["success"] and not (
                    c["success"] and c["time"] <= TIME_FACTOR * p["time"]))]

    def failure_lines(self) -> List[str]:
        """Why the reward is refused, the failing drives last ([] when accepted)."""
        if self.accepted:
            return []
        failing = self.failing_drives()
        return list(self.verdict["failures"]) + (
            [f"failing drives: {', '.join(failing)}"] if failing else [])

    def describe(self) -> str:
        """What was driven, drive by drive (and, refused, how to save the reward anyway)."""
        return ("The controller on the recorded drives (maps from their scans, people replayed "
                f"without reacting; barrier margin {self.margin:.2f} m): "
                + "; ".join(self.drive_lines())
                + ("" if self.accepted else " (learn_reward --accept-mismatch saves it regardless)"))

    def to_dict(self) -> Dict:
        figures = [{"drive": name, "person": _plain(p), "controller": _plain(c)}
                   for name, p, c in zip(self.names, self.person, self.controller)]
        return dict(_plain(self.verdict), failing_drives=self.failing_drives(), drives=figures,
                    method="the controller on each recording's own map and replayed people "
                           "(lfd_controller.recorded_check)")


def _outcome(figures: Dict) -> str:
    if figures["success"]:
        return f"arrived in {figures['time']:.1f} s"
    if figures["collision"]:
        return f"touched a {figures['collision']}"
    status = figures.get("status")
    return "did not arrive" + (f" ({status})" if status else "")


def _plain(figures: Dict) -> Dict:
    """YAML-safe figures: floats rounded, inf and nan as None."""
    def value(v):
        if isinstance(v, (bool, str)) or v is None:
            return v
        if isinstance(v, (float, np.floating, int, np.integer)):
            return round(float(v), 3) if math.isfinite(v) else None
        return [value(item) for item in v] if isinstance(v, list) else v
    return {k: value(v) for k, v in figures.items()}


def check_recorded(reward, drives: Sequence[Tuple[Demonstration, RecordedSensors]], *,
                   names: Optional[Sequence[str]] = None,
                   progress: Callable[[str], None] = lambda _: None) -> RecordedVerdict:
    """The acceptance check of `reward` on recorded drives (module docstring), one progress
    line per drive; DemonstrationError for a recording the check cannot use."""
    names = list(names) if names is not None else [f"drive {i + 1}" for i in range(len(drives))]
    worlds, person = [], []
    for name, (demo, sensors) in zip(names, drives):
        try:
            worlds.append(recorded_world(demo, sensors))
        except DemonstrationError as err:
            raise DemonstrationError(f"{name}: {err}") from err
        person.append(recorded_figures(demo.trajectory(), demo.t0, demo.scenario.dt,
                                       worlds[-1], np.asarray(sensors.path, float)[-1]))
    margin = room_margin([p["closest"] for p in person])
    config = RewardControllerParams().with_reward_settings({"barrier_margin": margin})
    controller = []
    with threadpool_limits(1):
        for index, (name, (demo, sensors), world, mine) in enumerate(
                zip(names, drives, worlds, person)):
            took = mine["time"] if mine["success"] else demo.length * demo.scenario.dt
            controller.append(controller_drive(reward, demo, sensors, world, config=config,
                                               time_limit=TIME_FACTOR * took + TIME_EXTRA))
            progress(f"acceptance {index + 1}/{len(drives)}: {name}: person {_outcome(mine)}, "
                     f"controller {_outcome(controller[-1])} "
                     f"({controller[-1]['cpu']:.1f} CPU-s)")
    verdict = hallway_acceptance(person, controller)
    if not any(p["success"] for p in person):       # nothing to hold the controller to
        verdict = {"accepted": False, "failures": [
            f"no recorded drive ends within {SUCCESS_TOLERANCE} m of its path's end without "
            "touching anything: nothing to check the controller against"]}
    return RecordedVerdict(verdict, margin, names, person, controller)
