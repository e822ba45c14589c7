"""Running navigation tasks (robot_common.tasks) in simulation: standard scenario files, whole
episodes under a policy, and the step-by-step episode state of the simulator node (no ROS)."""
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import numpy as np

from robot_common.errors import TaskError
from robot_common.tasks import Scenario, scenario_from_yaml
from robot_sim.errors import SimError

__all__ = ["load_scenario", "scenarios_dir", "EpisodeResult", "run_episode", "SimEpisode"]


def load_scenario(path_or_name: Union[str, Path]) -> Scenario:
    """A scenario from a YAML file path, or by name from robot_sim's config/scenarios/."""
    path = Path(path_or_name)
    if not path.suffix:
        path = scenarios_dir() / f"{path_or_name}.yaml"
    try:
        text = path.read_text()
    except OSError as err:
        raise TaskError(f"cannot read scenario file {path}: {err.strerror}") from err
    return scenario_from_yaml(text)


def scenarios_dir() -> Path:
    """robot_sim's config/scenarios folder (source tree layout)."""
    return Path(__file__).resolve().parents[2] / "config" / "scenarios"


@dataclass
class EpisodeResult:
    states: np.ndarray
    actions: np.ndarray
    times: np.ndarray
    reached: bool
    collided: bool
    min_clearance: float

    @property
    def success(self) -> bool:
        return self.reached and not self.collided


def run_episode(scenario: Scenario, policy: Callable[[np.ndarray, float], np.ndarray],
                start: np.ndarray, *, max_time: Optional[float] = None) -> EpisodeResult:
    """Drive from `start` with policy(state, t) -> action until the goal, a collision or timeout."""
    model = scenario.model()
    steps = int(round((max_time or scenario.max_time) / scenario.dt))
    states, actions, times = [np.asarray(start, float)], [], [0.0]
    reached = collided = False
    for k in range(steps):
        t = k * scenario.dt
        action = np.asarray(policy(states[-1], t), dtype=float)
        states.append(model.step(states[-1], action))
        actions.append(action)
        times.append(t + scenario.dt)
        if scenario.collides(states[-1], times[-1]):
            collided = True
            break
        if scenario.reached(states[-1]):
            reached = True
            break
    states_arr = np.array(states)
    clearance = scenario.obstacle_distance(states_arr, np.array(times)) - scenario.clearance
    return EpisodeResult(states_arr, np.array(actions).reshape(-1, 2), np.array(times), reached,
                         collided, float(clearance.min()))


class SimEpisode:
    """The simulator's state between resets: robot state, episode time, last command, status.

    Commands older than `command_timeout` seconds are replaced by zero (a robot base's safety
    stop). After a collision the robot stays where it hit (status "collided") until the next reset.
    """

    def __init__(self, scenario: Scenario, *, seed: Optional[int] = None, command_timeout: float = 0.5):
        self.scenario = scenario
        self.model = scenario.model()
        self.rng = np.random.default_rng(seed)
        self.command_timeout = command_timeout
        self.reset()

    def reset(self, start: Optional[Sequence[float]] = None) -> np.ndarray:
        """A new episode from `start` (x, y, yaw) or a random start; returns the state."""
        if start is None:
            self.state = self.scenario.sample_start(self.rng)
        else:
            values = [float(v) for v in start]
            if len(values) != 3 or not all(math.isfinite(v) for v in values):
                raise SimError(f"a start pose is (x, y, yaw), got {list(start)!r}")
            self.state = np.array(values + [0.0, 0.0])
        self.time = 0.0
        self.command = np.zeros(2)
        self._command_time = -math.inf
        self.status = "collided" if self.scenario.collides(self.state, 0.0) else "running"
        self.episode = getattr(self, "episode", 0) + 1
        return self.state

    def set_command(self, linear: float, angular: float) -> None:
        if not (math.isfinite(linear) and math.isfinite(angular)):
            raise SimError(f"command must be finite, got ({linear}, {angular})")
        self.command = np.array([linear, angular], dtype=float)
        self._command_time = self.time

    def step(self) -> np.ndarray:
        """Advances one dt; returns the command that was applied."""
        applied = self.command if self.time - self._command_time <= self.command_timeout + 1e-9 \
            else np.zeros(2)
        if self.status == "collided":
            applied = np.zeros(2)
            self.state = np.concatenate([self.state[:3], [0.0, 0.0]])
        else:
            self.state = self.model.step(self.state, applied)
        self.time += self.scenario.dt
        if self.status != "collided":
            if self.scenario.collides(self.state, self.time):
                self.status = "collided"
            elif self.scenario.reached(self.state):
                self.status = "reached"
            elif self.status == "reached":
                self.status = "running"
        return applied
