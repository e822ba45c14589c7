"""Driving through a building floor among people, with known ground truth (no ROS).

A `HallwayScene` is one task on a floor map (a generated building or a real map file): a start
and a goal 10-60 m apart along the halls, the path a grid planner (robot_common.gridplan) gives,
2-8 people with routes of their own and clutter the map does not have (disc obstacles: a cart, a
chair). People kinds, each placed relative to the robot's path:

  * `head_on` - walks the robot's path the other way, on its own right side;
  * `overtaking` - starts behind the robot and walks the same way faster;
  * `overtaken` - starts ahead and walks the same way slower;
  * `crossing` - walks across the hall from wall to wall, timed to meet the robot;
  * `group` - two or three people standing together beside the path (at a door, talking);
  * `stepping_out` - stands off the path (in a room's door) and steps onto it as the robot nears.

People follow their routes and do not steer round the robot (the robot must avoid them); one
who would walk into it waits until it is out of the way (`HallwayScene.advance`). The robot's
laser (`scan`) sees walls, clutter and people (robot_sim.crowd.disc_ranges); `tracked` is what a
people tracker reports: name, position and velocity of each person in range and in sight.
`collision` says what the robot touches.
"""
import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import numpy as np

from robot_common.gridplan import NoPathError, clearance_map, path_length, plan_path
from robot_common.maps import GridMap, raycast
from robot_common.polylines import arc_lengths, points_along
from robot_sim.crowd import disc_ranges
from robot_sim.errors import SimError

__all__ = ["PEOPLE_KINDS", "Walker", "HallwayScene", "make_scene", "Observation",
           "DriveResult", "observe", "drive", "hall_points", "keep_side", "PERSON_RADIUS"]

PEOPLE_KINDS = ("head_on", "overtaking", "overtaken", "crossing", "group", "stepping_out")
PERSON_RADIUS = 0.25


@dataclass
class Walker:
    """A person walking `route` (N, 2) at `speed` from time `depart` (standing before; gone
    once at the route's end, through a door); with `enters` true not there before `depart`
    either (coming round a corner), and not while the robot stands where they would come in
    (`outside`). A person with speed 0 stands at route[0] all the time."""

    name: str
    kind: str
    route: np.ndarray
    speed: float = 0.0
    depart: float = 0.0
    enters: bool = False
    held: float = 0.0               # seconds spent waiting for the robot so far
    holding: bool = False           # waiting now
    entered: bool = False           # came round the corner (`enters`)
    _arc: Optional[np.ndarray] = field(default=None, init=False, repr=False, compare=False)

    @property
    def outside(self) -> bool:
        """Waiting round the corner: due to come in, with the robot in the way in."""
        return self.enters and self.holding and not self.entered

    def arc(self) -> np.ndarray:
        """The route's arc lengths (worked out once: a route does not change)."""
        if self._arc is None:
            self._arc = arc_lengths(np.asarray(self.route, float))
        return self._arc

    def walked(self, t: float) -> float:
        """Walking time at scene time t (after departing, less the time held)."""
        return max(0.0, t - self.depart - self.held)

    def present(self, t: float) -> bool:
        if self.speed <= 0:
            return True
        if self.enters and (t < self.depart or self.outside):
            return False
        return self.walked(t) * self.speed < self.arc()[-1]

    def position(self, t: float) -> np.ndarray:
        if self.speed <= 0 or len(self.route) < 2:
            return np.asarray(self.route[0], float).copy()
        return points_along(self.route, [self.walked(t) * self.speed], self.arc())[0]

    def velocity(self, t: float, span: float = 0.1) -> np.ndarray:
        if self.holding or self.speed <= 0:
            return np.zeros(2)
        return (self.position(t + span) - self.position(t)) / span

    def yield_to(self, robot, t: float, dt: float, room: float) -> None:
        """Wait this step (hold) when walking on would bring the person within `room` m (centre
        to centre) of the robot at `robot` (x, y) in front of them: people do not walk into a
        robot, nor come round a corner onto it (`enters`: waiting outside while the robot is
        within `room` of route[0])."""
        self.holding = False
        if self.enters and not self.entered and self.speed > 0 and t + dt >= self.depart:
            if np.hypot(*(np.asarray(self.route[0], float) - robot)) < room:
                self.held += dt
                self.holding = True
                return
            self.entered = True
        if self.speed <= 0 or not self.present(t) or t + dt <= self.depart:
            return      # (the step they set off in counts: they would walk into it there too)
        here, there = self.position(t), self.position(t + dt)
        ahead = np.dot(there - here, np.asarray(robot) - here) > 0
        if ahead and np.hypot(*(there - robot)) < room:
            self.held += dt
            self.holding = True


@dataclass
class HallwayScene:
    """One drive through a floor (see the module docstring)."""

    grid: GridMap
    path: np.ndarray
    start: np.ndarray                  # (x, y, yaw, v, w)
    people: List[Walker]
    clutter: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))   # (x, y, radius)
    robot_radius: float = 0.18
    goal_tolerance: float = 0.3
    dt: float = 0.1
    name: str = "hallway"

    @property
    def goal(self) -> np.ndarray:
        return np.asarray(self.path[-1], float)

    @property
    def length(self) -> float:
        return path_length(self.path)

    @property
    def max_time(self) -> float:
        """Time allowed: the path at 0.2 m/s plus 20 s."""
        return self.length / 0.2 + 20.0

    def reset(self) -> None:
        """Back to the scene's start (nobody has waited yet)."""
        for walker in self.people:
            walker.held, walker.holding = 0.0, False
            walker.entered = False

    def advance(self, robot, t: float, dt: float) -> None:
        """The people's step from t to t + dt with the robot at (x, y): who would walk into it
        waits (Walker.yield_to)."""
        room = self.robot_radius + PERSON_RADIUS + 0.25
        for walker in self.people:
            walker.yield_to(np.asarray(robot, float)[:2], t, dt, room)

    def present(self, t: float) -> List[Walker]:
        return [w for w in self.people if w.present(t)]

    def people_at(self, t: float) -> np.ndarray:
        """Positions (P, 2) of the people present at time t."""
        return np.array([w.position(t) for w in self.present(t)]).reshape(-1, 2)

    def velocities_at(self, t: float) -> np.ndarray:
        return np.array([w.velocity(t) for w in self.present(t)]).reshape(-1, 2)

    def scan(self, pose, t: float, angles: np.ndarray, max_range: float) -> np.ndarray:
        """Laser ranges from `pose` (x, y, yaw) at time t: walls, clutter and people."""
        x, y, yaw = (float(v) for v in pose[:3])
        world = yaw + np.asarray(angles, float)
        ranges = np.minimum(raycast(self.grid, x, y, world, max_range),
                            disc_ranges(x, y, world, self.people_at(t), PERSON_RADIUS))
        for cx, cy, radius in self.clutter:
            ranges = np.minimum(ranges, disc_ranges(x, y, world, np.array([[cx, cy]]), radius))
        return np.minimum(ranges, max_range)

    def tracked(self, pose, t: float, max_range: float = 8.0
                ) -> Tuple[List[str], np.ndarray, np.ndarray]:
        """(names, positions (P, 2), velocities (P, 2)) of the people within `max_range` whom no
        wall hides (a tracker's report, without noise)."""
        x, y = float(pose[0]), float(pose[1])
        names, positions, velocities = [], [], []
        for walker in self.present(t):
            where = walker.position(t)
            offset = where - (x, y)
            distance = float(np.hypot(*offset))
            if distance > max_range:
                continue
            wall = raycast(self.grid, x, y, np.array([math.atan2(offset[1], offset[0])]),
                           max_range)[0]
            if wall + 0.15 >= distance - PERSON_RADIUS:
                names.append(walker.name)
                positions.append(where)
                velocities.append(walker.velocity(t))
        return names, np.array(positions).reshape(-1, 2), np.array(velocities).reshape(-1, 2)

    def collision(self, state, t: float) -> Optional[str]:
        """"wall", "person", "clutter" or None: what the robot at `state` touches at time t."""
        x, y, r = float(state[0]), float(state[1]), self.robot_radius
        ring = np.linspace(0, 2 * math.pi, 16, endpoint=False)
        if not self.grid.is_free(np.append(x + r * np.cos(ring), x),
                                 np.append(y + r * np.sin(ring), y)).all():
            return "wall"
        people = self.people_at(t)
        if len(people) and np.hypot(*(people - (x, y)).T).min() < r + PERSON_RADIUS:
            return "person"
        if len(self.clutter) and (np.hypot(self.clutter[:, 0] - x, self.clutter[:, 1] - y)
                                  < r + self.clutter[:, 2]).any():
            return "clutter"
        return None

    def reached(self, state) -> bool:
        return float(np.hypot(*(np.asarray(state[:2], float) - self.goal))) < self.goal_tolerance

    def person_gap(self, state, t: float) -> float:
        """Distance (m) between the robot's edge and the nearest person's (inf: nobody)."""
        people = self.people_at(t)
        if not len(people):
            return math.inf
        centre = float(np.hypot(*(people - np.asarray(state[:2], float)).T).min())
        return centre - self.robot_radius - PERSON_RADIUS


def hall_points(grid: GridMap, rng, count: int, clearance: float) -> np.ndarray:
    """`count` random free points at least `clearance` m from any wall (hall-like spots)."""
    coarse = grid.downsample(max(1, int(round(0.1 / grid.resolution))))
    room = clearance_map(coarse, clearance)
    rows, cols = np.nonzero(room >= clearance)
    if not len(rows):
        raise SimError(f"no spot of the map is {clearance} m clear of walls")
    pick = rng.integers(len(rows), size=count)
    return np.column_stack(coarse.cell_to_world(rows[pick], cols[pick]))


def make_scene(grid: GridMap, seed: int, *, people: int = 4, clutter: int = 1,
               length: Sequence[float] = (10.0, 60.0), kinds: Sequence[str] = PEOPLE_KINDS,
               name: str = "hallway") -> HallwayScene:
    """A random drive on `grid` (see the module docstring): start and goal with a planned path
    `length` m long (SimError when 200 tries find none), `people` people of the `kinds` in turn
    (a group counts its members), `clutter` discs on the path away from its ends."""
    if not 0 <= people <= 8:
        raise SimError(f"a scene has 0-8 people, got {people}")
    unknown = sorted(set(kinds) - set(PEOPLE_KINDS))
    if unknown or not kinds:
        raise SimError(f"people kinds must be some of {PEOPLE_KINDS}, got {list(kinds)}")
    rng = np.random.default_rng(seed)
    path = _route(grid, rng, length)
    heading = math.atan2(*(path[min(5, len(path) - 1)] - path[0])[::-1])
    start = np.array([path[0][0], path[0][1], heading + rng.uniform(-0.3, 0.3), 0.0, 0.0])
    scene = HallwayScene(grid, path, start, [], name=name)
    walkers: List[Walker] = []
    kind_order = list(kinds)
    while len(walkers) < people:
        kind = kind_order[len(walkers) % len(kind_order)] if len(walkers) else \
            kind_order[int(rng.integers(len(kind_order)))]
        walkers += _walkers(scene, kind, rng, len(walkers), people - len(walkers))
    scene.people = walkers
    scene.clutter = _clutter(scene, rng, clutter)
    return scene


def _route(grid: GridMap, rng, length: Sequence[float]) -> np.ndarray:
    for _ in range(200):
        ends = hall_points(grid, rng, 2, 0.7)
        straight = float(np.hypot(*(ends[1] - ends[0])))
        if not 0.5 * length[0] <= straight <= length[1]:
            continue
        try:
            path = plan_path(grid, ends[0], ends[1], clearance=0.35)
        except NoPathError:
            continue
        if length[0] <= path_length(path) <= length[1]:
            return path
    raise SimError(f"no start and goal {length[0]}-{length[1]} m apart along the halls")


def _free_beside(scene: HallwayScene, point, normal, distances) -> Optional[np.ndarray]:
    """The first of `point + d * normal` (d in distances) clear of walls by a person's radius."""
    for d in distances:
        spot = np.asarray(point) + d * np.asarray(normal)
        ring = np.linspace(0, 2 * math.pi, 8, endpoint=False)
        if scene.grid.is_free(spot[0] + 0.3 * np.cos(ring), spot[1] + 0.3 * np.sin(ring)).all():
            return spot
    return None


def _walkers(scene: HallwayScene, kind: str, rng, index: int, room: int) -> List[Walker]:
    """People of one kind (a group may be 2-3 of them; `room` is how many may still come)."""
    path, total = scene.path, scene.length
    along = rng.uniform(0.3, 0.8) * total
    point = points_along(path, [along])[0]
    tangent = points_along(path, [along + 0.5])[0] - points_along(path, [along - 0.5])[0]
    tangent = tangent / max(float(np.hypot(*tangent)), 1e-9)
    normal = np.array([-tangent[1], tangent[0]])
    speed = rng.uniform(0.8, 1.3)
    robot_eta = along / 0.45            # about when a robot at 0.45 m/s gets there
    name = f"person{index}"
    if kind in ("head_on", "overtaking", "overtaken"):
        side = {"head_on": -1.0, "overtaking": 1.0, "overtaken": -1.0}[kind]   # keep right
        depart, enters = 0.0, False
        if kind == "head_on":
            stations = np.linspace(min(total, along + robot_eta * speed * 0.5), 0.0, 40)
        elif kind == "overtaking":
            stations, speed = np.linspace(0.0, total, 60), rng.uniform(0.9, 1.3)
            depart, enters = rng.uniform(4.0, 10.0), True
        else:
            stations = np.linspace(rng.uniform(2.0, 5.0), total, 60)
            speed = rng.uniform(0.2, 0.3)
        route = keep_side(scene.grid, scene.path, stations, side)
        return [Walker(name, kind, route, speed, depart, enters)]
    if kind == "crossing":
        ends = [_wall_end(scene, point, s * normal) for s in (1.0, -1.0)]
        route = np.array(ends) if rng.random() < 0.5 else np.array(ends[::-1])
        span = float(np.hypot(*(route[1] - route[0])))
        return [Walker(name, kind, route, speed, depart=max(0.0, robot_eta - span / (2 * speed)))]
    if kind == "group":
        size = int(min(room, rng.integers(2, 4)))
        side = 1.0 if rng.random() < 0.5 else -1.0
        centre = _free_beside(scene, point, side * normal, (1.1, 0.9, 0.7)) if size else None
        if centre is None:          # no room beside the path here: someone walking instead
            return _walkers(scene, "head_on", rng, index, room)
        spots = [centre + 0.55 * k * tangent for k in range(size)]
        return [Walker(f"person{index + k}", kind, np.array([spot])) for k, spot in enumerate(spots)]
    # stepping_out: from beside the path (a door) onto it, then along it away from the robot
    side = 1.0 if rng.random() < 0.5 else -1.0
    off = _wall_end(scene, point, side * normal)
    stations = np.linspace(along, min(total, along + 8.0), 10)
    route = np.vstack([[off], points_along(path, stations)])
    return [Walker(name, "stepping_out", route, rng.uniform(0.6, 1.0),
                   depart=max(0.0, robot_eta - 4.0))]


def keep_side(grid: GridMap, path: np.ndarray, stations: np.ndarray, side: float,
              wanted: float = 0.75) -> np.ndarray:
    """Points at `stations` along the path, `wanted` m to the `side` (+1 left, -1 right) of it,
    less where the hall is narrower (a person's radius + 0.1 m from the wall)."""
    points = points_along(path, stations)
    normals = side * _normals(path, stations)
    reach = np.array([raycast(grid, float(p[0]), float(p[1]),
                              np.array([math.atan2(n[1], n[0])]), wanted + 1.0)[0]
                      for p, n in zip(points, normals)])
    offsets = np.clip(reach - PERSON_RADIUS - 0.1, 0.0, wanted)
    return points + offsets[:, None] * normals


def _normals(path: np.ndarray, stations: np.ndarray) -> np.ndarray:
    ahead = points_along(path, stations + 0.5) - points_along(path, stations - 0.5)
    ahead = ahead / np.maximum(np.hypot(*ahead.T), 1e-9)[:, None]
    return np.column_stack([-ahead[:, 1], ahead[:, 0]])


def _wall_end(scene: HallwayScene, point, direction) -> np.ndarray:
    """The free point toward `direction` from `point`, a person's radius + 0.1 m off the wall
    (at most 4 m away)."""
    direction = np.asarray(direction, float)
    reach = raycast(scene.grid, float(point[0]), float(point[1]),
                    np.array([math.atan2(direction[1], direction[0])]), 4.0)[0]
    return np.asarray(point) + max(0.0, reach - PERSON_RADIUS - 0.1) * direction


def _clutter(scene: HallwayScene, rng, count: int) -> np.ndarray:
    """Discs (x, y, r) beside the path, between 25 % and 85 % of it, that leave a way past."""
    items = []
    for _ in range(count):
        along = rng.uniform(0.25, 0.85) * scene.length
        point = points_along(scene.path, [along])[0]
        normal = _normals(scene.path, np.array([along]))[0]
        radius = rng.uniform(0.2, 0.35)
        for offset in (0.3, -0.3, 0.6, -0.6):
            spot = point + offset * normal
            ring = np.linspace(0, 2 * math.pi, 12, endpoint=False)
            room = radius + 2 * scene.robot_radius + 0.3
            if scene.grid.is_free(spot[0] + room * np.cos(ring), spot[1] + room * np.sin(ring)).sum() >= 6:
                items.append((spot[0], spot[1], radius))
                break
    return np.array(items, float).reshape(-1, 3)


@dataclass
class Observation:
    """What the robot has at one step: its laser (angles in the robot frame, ranges) and the
    tracked people (names, positions, velocities; map frame)."""

    angles: np.ndarray
    ranges: np.ndarray
    names: List[str]
    people: np.ndarray
    velocities: np.ndarray


@dataclass
class DriveResult:
    states: np.ndarray          # x_0..x_T (T + 1, 5)
    actions: np.ndarray         # (T, 2)
    reached: bool
    collision: Optional[str]    # "wall", "person", "clutter" or None
    person_gaps: np.ndarray     # (T + 1,) edge-to-edge distance to the nearest person

    @property
    def success(self) -> bool:
        return self.reached and self.collision is None

    dt: float = 0.1

    @property
    def time(self) -> float:
        """Seconds to the goal (nan: not reached)."""
        return len(self.actions) * self.dt if self.reached else math.nan


def observe(scene: HallwayScene, state, t: float, *, beams: int = 72,
            max_range: float = 8.0) -> Observation:
    angles = np.linspace(-math.pi, math.pi, beams, endpoint=False)
    names, people, velocities = scene.tracked(state, t, max_range)
    return Observation(angles, scene.scan(state, t, angles, max_range), names, people, velocities)


def drive(scene: HallwayScene, policy, *, model=None, max_time: Optional[float] = None,
          beams: int = 72) -> DriveResult:
    """Drive from the scene's start with policy(state, t, observation) -> (v_cmd, w_cmd) until
    the goal, a collision or the time limit (`model`: a robot_common Unicycle, default dt 0.1)."""
    from robot_common.unicycle import Unicycle
    model = model or Unicycle(scene.dt)
    state = np.asarray(scene.start, float)
    scene.reset()
    states, actions, gaps = [state], [], [scene.person_gap(state, 0.0)]
    reached, hit = False, None
    for k in range(int(round((max_time or scene.max_time) / model.dt))):
        t = k * model.dt
        action = np.asarray(policy(state, t, observe(scene, state, t, beams=beams)), float)
        scene.advance(state, t, model.dt)
        state = model.step(state, action)
        states.append(state)
        actions.append(action)
        gaps.append(scene.person_gap(state, t + model.dt))
        hit = scene.collision(state, t + model.dt)
        if hit is not None:
            break
        if scene.reached(state):
            reached = True
            break
    return DriveResult(np.array(states), np.array(actions).reshape(-1, 2), reached, hit,
                       np.array(gaps), model.dt)
