"""Demonstrations: start state, commands, episode time and scenario of one drive (no ROS).

A demonstration embeds its navigation task (robot_common.tasks.Scenario): goal, obstacle, robot
limits and time step; malformed stored demonstrations raise DemonstrationError.
"""
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

import numpy as np

from lfd_controller.errors import DemonstrationError
from robot_common.errors import ModelError, TaskError
from robot_common.tasks import Scenario, scenario_from_yaml


@dataclass
class Demonstration:
    """One demonstrated drive, sampled every scenario.dt seconds.

    start: x_0 = (px, py, yaw, v, w); actions: (T, 2) commands (v_cmd, w_cmd) applied one per
    step; t0: episode time of x_0 (indexes a moving obstacle); states: the recorded x_1..x_T
    (None: roll the model out).
    """

    scenario: Scenario
    start: np.ndarray
    actions: np.ndarray
    t0: float = 0.0
    states: Optional[np.ndarray] = None
    source: str = "synthetic"
    meta: Dict = field(default_factory=dict)

    def __post_init__(self):
        self.start = np.asarray(self.start, dtype=float)
        self.actions = np.asarray(self.actions, dtype=float)
        if self.start.shape != (5,) or not np.all(np.isfinite(self.start)):
            raise DemonstrationError(f"demonstration start must be 5 finite numbers, got {self.start!r}")
        if self.actions.ndim != 2 or self.actions.shape[1] != 2 or len(self.actions) < 2:
            raise DemonstrationError(f"demonstration actions must have shape (T >= 2, 2), got "
                                     f"{self.actions.shape}")
        if not np.all(np.isfinite(self.actions)):
            raise DemonstrationError("demonstration actions must be finite")
        if self.states is not None:
            self.states = np.asarray(self.states, dtype=float)
            if self.states.shape != (len(self.actions), 5):
                raise DemonstrationError(f"recorded states must have shape ({len(self.actions)}, 5), "
                                         f"got {self.states.shape}")

    @property
    def length(self) -> int:
        return len(self.actions)

    def rollout(self) -> np.ndarray:
        """x_1..x_T under the model (what learning uses)."""
        return self.scenario.model().rollout(self.start, self.actions)

    def trajectory(self) -> np.ndarray:
        """x_0..x_T: the recorded states when present, else the model rollout."""
        states = self.states if self.states is not None else self.rollout()
        return np.vstack([self.start, states])

    def times(self) -> np.ndarray:
        return self.t0 + self.scenario.dt * np.arange(self.length + 1)

    def to_dict(self) -> Dict:
        return {"scenario_yaml": self.scenario.to_yaml(), "start": self.start.tolist(),
                "actions": self.actions.tolist(), "t0": self.t0,
                "states": None if self.states is None else self.states.tolist(),
                "source": self.source, "meta": dict(self.meta)}

    @classmethod
    def from_dict(cls, data: Dict) -> "Demonstration":
        try:
            scenario = scenario_from_yaml(data["scenario_yaml"])
            return cls(scenario, data["start"], data["actions"], float(data.get("t0", 0.0)),
                       data.get("states"), str(data.get("source", "unknown")), dict(data.get("meta") or {}))
        except (KeyError, TypeError, ValueError, TaskError, ModelError) as err:
            raise DemonstrationError(f"malformed demonstration: {err}") from err


def check_same_dt(demos: Sequence[Demonstration]) -> float:
    if not demos:
        raise DemonstrationError("no demonstrations given")
    dts = sorted({round(d.scenario.dt, 9) for d in demos})
    if len(dts) != 1:
        raise DemonstrationError(f"demonstrations have different time steps {dts}")
    return dts[0]


def trim_to_goal(demo: Demonstration, extra_steps: int = 0) -> Demonstration:
    """The demonstration cut shortly after the robot first enters the goal region."""
    states = demo.rollout()
    inside = np.flatnonzero(demo.scenario.reached(states))
    if not len(inside):
        return demo
    end = min(len(states), inside[0] + 1 + extra_steps)
    return Demonstration(demo.scenario, demo.start, demo.actions[:end], demo.t0,
                         None if demo.states is None else demo.states[:end], demo.source, demo.meta)


def smooth_commands(demo: Demonstration, window: int = 5) -> Demonstration:
    """The demonstration with its commands averaged over `window` steps (a centred moving average;
    1: unchanged): what a person meant with a quantised, noisy stick rather than the stick's jitter.
    The recorded states are dropped (they belong to the raw commands); learning rolls out the
    smoothed commands through the model."""
    if window < 1:
        raise DemonstrationError(f"smoothing window must be >= 1 step, got {window!r}")
    if window == 1:
        return demo
    kernel = np.ones(window) / window
    padded = np.pad(demo.actions, ((window // 2, window - 1 - window // 2), (0, 0)), mode="edge")
    actions = np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in (0, 1)])
    return Demonstration(demo.scenario, demo.start, actions, demo.t0, None, demo.source,
                         dict(demo.meta, smoothed=window))


def windows(demo: Demonstration, length: int, stride: Optional[int] = None) -> List[Demonstration]:
    """The demonstration cut into pieces of `length` steps every `stride` steps (default: length),
    each starting from the state recorded there (the model rollout when none was recorded) at its
    episode time. A person re-decides all the time, as a receding-horizon controller does: each
    piece is a locally optimal plan from where the person was, not a part of one plan made at the
    start. A demonstration shorter than `length` stays whole; a last piece shorter than
    length / 2 is dropped."""
    if length < 2:
        raise DemonstrationError(f"window length must be >= 2 steps, got {length!r}")
    stride = length if stride is None else int(stride)
    if stride < 1:
        raise DemonstrationError(f"window stride must be >= 1 step, got {stride!r}")
    if demo.length <= length:
        return [demo]
    trajectory, times = demo.trajectory(), demo.times()
    pieces = []
    for first in range(0, demo.length - 1, stride):
        last = min(demo.length, first + length)
        if last - first < max(2, length // 2):
            break
        states = None if demo.states is None else demo.states[first:last]
        pieces.append(Demonstration(demo.scenario, trajectory[first], demo.actions[first:last],
                                    float(times[first]), states, demo.source,
                                    dict(demo.meta, window=[first, last])))
    return pieces


def demos_summary(demos: List[Demonstration]) -> str:
    lengths = [d.length for d in demos]
    return (f"{len(demos)} demonstrations, {sum(lengths)} steps "
            f"({min(lengths)}-{max(lengths)} per demo)") if demos else "no demonstrations"
