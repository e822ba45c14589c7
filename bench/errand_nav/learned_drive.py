"""Driving a planned path among simulated people with lfd_controller's learned controller.

The robot is what reward_controller runs in path mode: `lfd_controller.hallway.
HallwayController` with a taught hallway reward (a file of lfd_controller.learning.save_reward,
its `info.controller` settings applied: the barrier margin), on a unicycle at 0.1 s steps. The
people are crowd_drive's (robot_sim.crowd at the hour's true densities, standing; the same
seed gives the same people as the pure-pursuit follower; one who would appear on the robot
stands beside it; after the robot has stood still 1 s, people in its lane within 1 m step
sideways). The controller sees them as robot_sim.hallway shows its walkers
(`robot_sim.hallway.observe`: a 72-beam laser to 8 m, raycast against the walls plus the people's
discs, and the people tracker's report: names, positions and velocities of the people in range
whom no wall hides): the people within 9 m of the robot are made standing `Walker`s of a
`HallwayScene` on the floor's map each step.

Outcome as crowd_drive's: reached (within 0.3 m of the goal before `limit` s), collisions (the
robot's disc touching a wall cell of the floor's own map ends the drive: robot_sim.hallway's
`HallwayScene.collision`; crowd_drive's test on its 0.1 m clearance map, up to a cell more
cautious, is counted apart as `coarse_wall_steps`: the follower never goes there, the learned
controller sees the real walls in its scan; each 0.1 s step closer than the two radii less
0.02 m to a person counts one), people met (distinct people
within `meet_radius`, centre to centre), time; plus the controller's last status ("blocked: ..."
after 20 s held up: the drive ends there), the seconds stood still (speed under 0.05 m/s) and
the people within 1.5 m / 3 m while standing, and the CPU of the controller's cycles.
"""
import math
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
from crowd_drive import DT as FOLLOWER_DT
from crowd_drive import ROBOT_RADIUS, Floor, make_way, step_aside, touching

from lfd_controller.hallway import HALLWAY_SAFETY, HallwayController
from lfd_controller.learning import controller_settings, load_reward
from robot_common.polylines import point_at
from robot_common.unicycle import Unicycle
from robot_sim.crowd import Crowd
from robot_sim.hallway import PERSON_RADIUS, HallwayScene, Walker, observe

STEP = 0.1            # s: the controller's cycle
SEEN = 9.0            # m: people further than this are neither scanned nor tracked (8 m laser)
STILL = 0.05          # m/s: standing still


@dataclass
class LearnedOutcome:
    reached: bool
    collisions: int
    wall: bool
    met: int
    seconds: float
    status: str = ""
    progress: float = 0.0       # share of the path covered when the drive ended
    coarse_wall_steps: int = 0  # steps within the robot's radius of a wall on the 0.1 m map
    still_seconds: float = 0.0
    near_still: List[int] = field(default_factory=list)     # people within 1.5 m, each still step
    around_still: List[int] = field(default_factory=list)   # people within 3 m, each still step
    cycle_cpu: List[float] = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.reached and self.collisions == 0

    @property
    def blocked(self) -> bool:
        return self.status.startswith("blocked")


class LearnedDriver:
    """A taught reward and its controller settings, loaded once."""

    def __init__(self, reward_file: str, budget: Optional[float] = None):
        self.reward = load_reward(reward_file)
        self.safety = dict(HALLWAY_SAFETY)
        self.safety.update({k: float(v) for k, v in controller_settings(reward_file).items()
                            if k in self.safety})
        self.budget = budget

    def drive(self, floor: Floor, grid, sim, points: np.ndarray, depart_hours: float, *,
              meet_radius: float, seed: int, limit: float) -> LearnedOutcome:
        """Drive `points` (N, 2) leaving at `depart_hours` among `sim`'s people (crowd seed
        `seed`) for at most `limit` s."""
        points = np.asarray(points, float)
        state, model = start_state(points), Unicycle(STEP)
        controller = HallwayController(self.reward, points, model, budget=self.budget,
                                       safety=dict(self.safety), grid=grid)
        scene = HallwayScene(grid, points, state.copy(), [])
        crowd = Crowd(sim, radius=PERSON_RADIUS, seed=seed)
        met, waited = set(), 0.0
        out = LearnedOutcome(False, 0, False, 0, 0.0)
        t = 0.0
        for k in range(int(math.ceil(limit / STEP))):
            t = k * STEP
            crowd.advance(t, depart_hours + t / 3600.0)
            pose = state[:2]
            step_aside(crowd, pose)
            gap = np.hypot(*(crowd.xy - pose).T) if crowd.xy.size else np.zeros(0)
            met.update(crowd.names[gap <= meet_radius].tolist())
            out.reached = bool(np.hypot(*(pose - points[-1])) < 0.3)
            if out.reached or controller.status_.startswith("blocked"):
                break
            close = gap < SEEN
            command = self._act(controller, scene, crowd, close, state, t, out)
            if abs(state[3]) < STILL:
                out.still_seconds += STEP
                out.near_still.append(int((gap < 1.5).sum()))
                out.around_still.append(int((gap < 3.0).sum()))
            waited = waited + STEP if abs(state[3]) < STILL else 0.0
            if waited > 1.0 and k % int(round(FOLLOWER_DT / STEP)) == 0:
                make_way(crowd, pose, float(state[2]))   # the follower's make-way, every 0.2 s
            state = model.step(state, np.asarray(command, float))
            t = (k + 1) * STEP
            out.coarse_wall_steps += int(floor.clearance_at(state[None, :2])[0] < ROBOT_RADIUS)
            scene.people = []
            out.wall = scene.collision(state, t) == "wall"
            out.collisions += int(out.wall or touching(state, crowd.xy[close]))
            if out.wall:
                break
        out.met, out.seconds, out.status = len(met), t, controller.status_
        out.progress = 1.0 if out.reached else \
            controller.follower.progress / max(controller.follower.length, 1e-9)
        return out

    @staticmethod
    def _act(controller, scene, crowd, close, state, t: float, out: LearnedOutcome):
        """The controller's command from what it sees: the `close` people as standing walkers
        of the scene (robot_sim.hallway.observe: scan and tracked people)."""
        scene.people = [Walker(f"p{n}", "standing", xy[None].copy())
                        for n, xy in zip(crowd.names[close], crowd.xy[close])]
        seen = observe(scene, state, t)
        began = time.process_time()
        command = controller.act(state, t, seen.angles, seen.ranges, seen.people,
                                 seen.velocities)
        out.cycle_cpu.append(time.process_time() - began)
        return command


def start_state(points: np.ndarray) -> np.ndarray:
    """(x, y, yaw, v, w) at the path's start, facing 0.4 m along it, standing."""
    ahead = point_at(points, 0.4)
    heading = math.atan2(ahead[1] - points[0][1], ahead[0] - points[0][0])
    return np.array([points[0][0], points[0][1], heading, 0.0, 0.0])


def summary(outcomes: List[LearnedOutcome]) -> Dict:
    """Stood-still and cycle figures over drives."""
    cycles = np.concatenate([o.cycle_cpu for o in outcomes]) if outcomes else np.zeros(0)
    near = np.concatenate([o.near_still for o in outcomes] + [np.zeros(0)])
    around = np.concatenate([o.around_still for o in outcomes] + [np.zeros(0)])
    return {"blocked": int(sum(o.blocked for o in outcomes)),
            "still_seconds": float(np.mean([o.still_seconds for o in outcomes])),
            "near_still_mean": float(near.mean()) if near.size else float("nan"),
            "around_still_mean": float(around.mean()) if around.size else float("nan"),
            "cycle_cpu_ms_mean": 1e3 * float(cycles.mean()) if cycles.size else float("nan"),
            "cycle_cpu_ms_p95": 1e3 * float(np.percentile(cycles, 95)) if cycles.size
            else float("nan")}
