"""A robot driven by velocity commands on a building floor among walking people (no ROS).

`FloorSim` is the state of the `building_sim` node between its steps: a unicycle
(robot_common.unicycle) whose command lapses after `command_timeout` simulated seconds (a silent
driver means stop), people walking their own routes through the halls (robot_sim.hallway.Walker:
one who would walk into the robot waits), clutter added at run time (discs the map lacks), the
laser (walls, clutter, people) and a people tracker's report with velocities
(robot_sim.hallway.HallwayScene). A collision with a wall, clutter or a person stops the robot
where it hit until it is put somewhere else (`place`).

People (`floor_walkers`): each walks back and forth between two spots of the halls along the
grid planner's path (robot_common.gridplan), keeping right, pausing 0-3 s at the ends, at
0.7-1.3 m/s, starting at a random point of the round; one who has waited 5 s for the robot
goes another way (`FloorSim` with a `RoundPlanner`: a new round from where they stand, planned
round the robot; without: back the way they came). Spots: on a generated building anywhere
in its halls; on a map file anywhere 0.7 m clear of walls (robot_sim.hallway.hall_points); or,
given a people model (robot_sim.people.PeopleSimulator) and an hour of the week, as many people
as its halls hold on average at that hour, their spots drawn in proportion to its densities.
"""
import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

from robot_common.gridplan import NoPathError, path_length, plan_path
from robot_common.maps import OCCUPIED, GridMap
from robot_common.unicycle import Unicycle, UnicycleLimits
from robot_sim.building import Building
from robot_sim.errors import SimError
from robot_sim.hallway import PERSON_RADIUS, HallwayScene, Walker, hall_points, keep_side
from robot_sim.people import PeopleSimulator

__all__ = ["FloorSim", "RoundPlanner", "floor_walkers", "crowd_size", "default_start"]

SPEEDS = (0.7, 1.3)          # walking speeds (m/s)
PAUSE = 3.0                  # longest pause at the end of a route (s)
PATIENCE = 5.0               # who has waited this long for the robot turns back (s)
KEEP_CLEAR = 1.0             # nobody starts closer than this to the robot (m, centre to centre)


class FloorSim:
    """The robot, the people and the clutter of one floor (see the module docstring).

    Args:
        grid: the floor map.
        people: the walkers (`floor_walkers`), their routes in scene time.
        start: (x, y, yaw) of the robot.
        dt: simulated seconds per step.
        command_timeout: simulated seconds a command holds.
        robot_radius: the robot's disc (m).
        limits: the unicycle's speed and acceleration limits.
        laser_x: the laser's distance ahead of the robot's centre (m).
        planner: gives who has waited PATIENCE s for the robot a new round from where they
            stand, round the robot; None: they walk back the way they came.
    """

    def __init__(self, grid: GridMap, people: List[Walker], start: Sequence[float], *,
                 dt: float = 0.05, command_timeout: float = 0.5, robot_radius: float = 0.18,
                 limits: UnicycleLimits = UnicycleLimits(), laser_x: float = 0.1,
                 planner: Optional["RoundPlanner"] = None):
        if not (dt > 0 and command_timeout >= 0 and robot_radius > 0):
            raise SimError(f"bad settings: dt={dt} command_timeout={command_timeout} "
                           f"robot_radius={robot_radius}")
        self.model = Unicycle(dt, limits)
        self.dt, self.command_timeout, self.laser_x = dt, command_timeout, laser_x
        self.planner = planner
        start = _pose(start)
        self.scene = HallwayScene(grid, np.array([start[:2]]), np.append(start, [0.0, 0.0]),
                                  list(people), robot_radius=robot_radius, dt=dt, name="floor")
        self.rounds = {w.name: (w.route, w.speed) for w in people}
        self.waited = {w.name: 0.0 for w in people}
        self.rng = np.random.default_rng(len(people))
        self.time = 0.0
        self.steps = 0
        self.place(start)

    @property
    def status(self) -> str:
        return "running" if self.hit is None else f"collided with {self.hit}"

    def place(self, pose: Sequence[float]) -> np.ndarray:
        """Put the robot at (x, y, yaw), standing, with no command (SimError: not a pose)."""
        self.state = np.append(_pose(pose), [0.0, 0.0])
        self.command = np.zeros(2)
        self._command_time = -math.inf
        self.hit = self.scene.collision(self.state, self.time)
        return self.state

    def set_command(self, linear: float, angular: float) -> None:
        if not (math.isfinite(linear) and math.isfinite(angular)):
            raise SimError(f"a command must be finite, got ({linear}, {angular})")
        self.command = np.array([linear, angular], float)
        self._command_time = self.time

    def add_obstacle(self, x: float, y: float, radius: float) -> int:
        """A disc the map lacks at (x, y); returns how many there are now."""
        if not (math.isfinite(x) and math.isfinite(y) and radius > 0):
            raise SimError(f"an obstacle needs a finite point and a positive radius, got "
                           f"({x}, {y}) radius {radius}")
        self.scene.clutter = np.vstack([self.scene.clutter, [[x, y, radius]]])
        return len(self.scene.clutter)

    def clear_obstacles(self) -> int:
        """Removes the added discs; returns how many there were."""
        count = len(self.scene.clutter)
        self.scene.clutter = np.zeros((0, 3))
        return count

    def step(self) -> np.ndarray:
        """One dt: people walk (waiting for the robot), the robot drives under the live command
        unless it has collided. Returns the command applied."""
        fresh = self.time - self._command_time <= self.command_timeout + 1e-9
        applied = self.command if fresh and self.hit is None else np.zeros(2)
        self.scene.advance(self.state[:2], self.time, self.dt)
        if self.hit is None:
            self.state = self.model.step(self.state, applied)
        self.time += self.dt
        self.steps += 1
        self._turn_back()
        self._renew()
        if self.hit is None:
            self.hit = self.scene.collision(self.state, self.time)
            if self.hit is not None:
                self.state[3:] = 0.0
        return applied

    def _renew(self) -> None:
        """Who has finished a round starts the next one after a pause."""
        for index, walker in enumerate(self.scene.people):
            if not walker.present(self.time):
                route, speed = self.rounds[walker.name]
                pause = float(self.rng.uniform(0.0, PAUSE))
                self.scene.people[index] = Walker(walker.name, walker.kind, route, speed,
                                                  depart=self.time + pause)

    def _turn_back(self) -> None:
        """Who has waited PATIENCE seconds for the robot goes another way."""
        for index, walker in enumerate(self.scene.people):
            self.waited[walker.name] = self.waited[walker.name] + self.dt if walker.holding else 0.0
            if self.waited[walker.name] >= PATIENCE:
                self.waited[walker.name] = 0.0
                self.scene.people[index] = self._another_way(walker)

    def _another_way(self, walker: Walker) -> Walker:
        """A new round from where `walker` stands round the robot (with a planner), else back the
        way they came."""
        here = walker.position(self.time)
        if self.planner is not None:
            room = self.scene.robot_radius + PERSON_RADIUS + 0.1
            try:
                route = self.planner.round(start=here, avoid=(*self.state[:2], room), tries=5)
            except SimError:
                pass
            else:
                self.rounds[walker.name] = (route, walker.speed)
                return Walker(walker.name, walker.kind, route, walker.speed, depart=self.time)
        behind = walker.route[walker.arc() < walker.walked(self.time) * walker.speed][::-1]
        return Walker(walker.name, walker.kind, np.vstack([here, behind]), walker.speed,
                      depart=self.time)

    def laser_pose(self) -> Tuple[float, float, float]:
        x, y, yaw = (float(v) for v in self.state[:3])
        return x + self.laser_x * math.cos(yaw), y + self.laser_x * math.sin(yaw), yaw

    def scan(self, angles: np.ndarray, max_range: float) -> np.ndarray:
        """Ranges along the laser's `angles` (walls, clutter, people)."""
        return self.scene.scan(self.laser_pose(), self.time, angles, max_range)

    def tracked(self, max_range: float) -> Tuple[List[str], np.ndarray, np.ndarray]:
        """A tracker's people (names, positions, velocities): in range and in sight."""
        return self.scene.tracked(self.state, self.time, max_range)

    def truth(self) -> Tuple[List[str], np.ndarray, np.ndarray]:
        """Every person on the floor (names, positions, velocities)."""
        present = self.scene.present(self.time)
        return ([w.name for w in present], self.scene.people_at(self.time),
                self.scene.velocities_at(self.time))


def _pose(pose: Sequence[float]) -> np.ndarray:
    values = [float(v) for v in pose]
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise SimError(f"a pose is [x, y, yaw], got {list(pose)!r}")
    return np.array(values)


def default_start(grid: GridMap, building: Optional[Building], seed: int) -> np.ndarray:
    """(x, y, yaw): a generated building's main hall 1.5 m from its west end, facing east; on a
    map file a spot 0.7 m clear of walls drawn from `seed`."""
    if building is not None:
        main = next(area for area in building.halls if area.name == "main_hall")
        return np.array([main.box[0] + 1.5, (main.box[1] + main.box[3]) / 2.0, 0.0])
    return np.append(hall_points(grid, np.random.default_rng(seed), 1, 0.7)[0], 0.0)


def crowd_size(people: PeopleSimulator, hours: float) -> float:
    """People the halls of `people` hold on average at `hours` (of the week)."""
    expected = people.expected_count(hours)[0]
    return float(expected[people.layout.hall >= 0].sum())


class RoundPlanner:
    """People's rounds on a floor: spots in its halls (see the module docstring) and the planned
    way out and back between two of them.

    Args:
        grid: the floor map.
        seed: seeds the spots.
        building: the generated building (its halls); None: a map file.
        crowd: a people model and the hour whose densities give the spots.
    """

    def __init__(self, grid: GridMap, seed: int, *, building: Optional[Building] = None,
                 crowd: Optional[Tuple[PeopleSimulator, float]] = None):
        self.grid, self.building, self.crowd = grid, building, crowd
        self.rng = np.random.default_rng(seed)

    def spots(self, count: int) -> np.ndarray:
        if self.crowd is not None:
            return _crowd_spots(self.grid, self.rng, count, *self.crowd)
        if self.building is None:
            return hall_points(self.grid, self.rng, count, 0.7)
        boxes = np.array([area.box for area in self.building.halls], float) + [0.5, 0.5, -0.5, -0.5]
        areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        pick = self.rng.choice(len(boxes), size=count, p=areas / areas.sum())
        low, high = boxes[pick, :2], boxes[pick, 2:]
        return low + self.rng.random((count, 2)) * (high - low)

    def round(self, *, start: Optional[Sequence[float]] = None,
              avoid: Optional[Tuple[float, float, float]] = None, tries: int = 20) -> np.ndarray:
        """Out and back between two spots at least 4 m apart (the first `start` if given) along
        the planner's path round the disc `avoid` (x, y, radius), keeping right (up to 0.5 m off
        its centre line), a point every 0.5 m, ending where it began (at `start` when given).
        SimError when `tries` pairs give no route."""
        grid = self.grid if avoid is None else _blocked(self.grid, *avoid)
        for _ in range(tries):
            ends = self.spots(2)
            if start is not None:
                ends[0] = start
            if np.hypot(*(ends[1] - ends[0])) < 4.0 or (avoid is not None and np.hypot(
                    ends[1][0] - avoid[0], ends[1][1] - avoid[1]) < avoid[2] + 1.0):
                continue
            try:
                path = plan_path(grid, ends[0], ends[1], clearance=PERSON_RADIUS + 0.05)
            except NoPathError:
                continue
            length = path_length(path)
            stations = np.append(np.arange(0.0, length, 0.5), length)
            out = keep_side(grid, path, stations, -1.0, 0.5)
            back = keep_side(grid, path[::-1], stations, -1.0, 0.5)
            # a closed loop from the very first point (`start` itself when given): the next
            # round and a new way round the robot begin where the person stands, never a step
            # aside in no time
            first = out[:1] if start is None else np.asarray(start, float).reshape(1, 2)
            return np.vstack([first, out, back, first])
        raise SimError(f"found no route for a person through the halls in {tries} tries")


def _blocked(grid: GridMap, x: float, y: float, radius: float) -> GridMap:
    """The map with a disc at (x, y) occupied."""
    cells = grid.cells.copy()
    rows, cols = np.indices(cells.shape)
    xs, ys = grid.cell_to_world(rows, cols)
    cells[np.hypot(xs - x, ys - y) < radius] = OCCUPIED
    return GridMap(cells, grid.resolution, grid.origin, dict(grid.meta))


def floor_walkers(planner: RoundPlanner, count: int, *,
                  keep_clear: Sequence[float] = ()) -> List[Walker]:
    """`count` people walking rounds (RoundPlanner.round) at 0.7-1.3 m/s, each starting at a
    random point of its round; none starts within 1 m of the point `keep_clear` (x, y) nor has
    a round ending there. SimError when the halls have no room for routes."""
    if count < 0:
        raise SimError(f"the number of people must be >= 0, got {count}")
    walkers = []
    avoid = None if len(keep_clear) < 2 else (float(keep_clear[0]), float(keep_clear[1]), KEEP_CLEAR)
    for index in range(count):
        route = planner.round(avoid=avoid)
        speed = float(planner.rng.uniform(*SPEEDS))
        walker = Walker(f"person{index}", "walking", route, speed)
        lap = path_length(route) / speed
        for _ in range(10):      # start at a random point of the round, away from the robot
            walker.depart = -float(planner.rng.uniform(0.0, lap))
            if avoid is None or np.hypot(*(walker.position(0.0) - avoid[:2])) > KEEP_CLEAR:
                break
        walkers.append(walker)
    return walkers


def _crowd_spots(grid: GridMap, rng, count: int, people: PeopleSimulator,
                 hours: float) -> np.ndarray:
    """Spots in hall cells drawn in proportion to the expected people there, clear of walls."""
    weight = people.expected_count(hours)[0] * (people.layout.hall >= 0)
    if not weight.sum() > 0:
        raise SimError(f"the people model has nobody in the halls at hour {hours}")
    cells = people.cells
    found: List[np.ndarray] = []
    ring = np.linspace(0, 2 * math.pi, 8, endpoint=False)
    for _ in range(50 * count):
        cell = rng.choice(len(weight), p=weight / weight.sum())
        spot = np.array([cells.x[cell], cells.y[cell]]) + (rng.random(2) - 0.5) * cells.cell_size
        reach = PERSON_RADIUS + 0.15
        if grid.is_free(spot[0] + reach * np.cos(ring), spot[1] + reach * np.sin(ring)).all():
            found.append(spot)
            if len(found) == count:
                return np.array(found)
    raise SimError("found no spot clear of walls in the people model's halls")
