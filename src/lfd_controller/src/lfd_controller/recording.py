"""Assembling a demonstration from simulator or robot samples (no ROS).

A sample is one step: the state reached, the command that was applied to reach it and the episode
time. Samples arrive from different topics; `SampleMatcher` pairs them by their header stamps (the
simulator stamps its odometry, applied command and time reference of one step alike).
"""
from typing import Dict, List, Optional

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError


class SampleMatcher:
    """Joins per-step parts ("state", "command", "time") that share a stamp key; keeps at most
    `max_pending` incomplete steps."""

    PARTS = ("state", "command", "time")

    def __init__(self, max_pending: int = 200):
        self.max_pending = max_pending
        self._pending: Dict[object, Dict[str, object]] = {}

    def add(self, key, part: str, value) -> Optional[Dict[str, object]]:
        """Adds a part; returns the complete step when this part completes it."""
        if part not in self.PARTS:
            raise ValueError(f"unknown sample part {part!r}")
        entry = self._pending.setdefault(key, {})
        entry[part] = value
        if all(name in entry for name in self.PARTS):
            del self._pending[key]
            return entry
        while len(self._pending) > self.max_pending:
            self._pending.pop(next(iter(self._pending)))
        return None


class DemoBuilder:
    """Collects steps between start() and stop() into a Demonstration."""

    def __init__(self, min_steps: int = 5):
        self.min_steps = min_steps
        self.recording = False
        self._last_state: Optional[np.ndarray] = None
        self._last_time: Optional[float] = None
        self._reset()

    def _reset(self):
        self.start_state: Optional[np.ndarray] = None
        self.t0 = 0.0
        self.states: List[np.ndarray] = []
        self.commands: List[np.ndarray] = []
        self.times: List[float] = []

    def observe(self, state, command, t: float) -> None:
        """One step: `state` reached at episode time `t` by applying `command`."""
        state, t = np.asarray(state, dtype=float), float(t)
        if self.recording:
            if self.start_state is None:
                self.start_state, self.t0 = state, t
            elif self._last_time is not None and t < self._last_time:
                self.recording = False     # the episode restarted: this drive ends here
            else:
                self.states.append(state)
                self.commands.append(np.asarray(command, dtype=float))
                self.times.append(t)
        self._last_state, self._last_time = state, t

    def start(self) -> None:
        if self.recording:
            raise DemonstrationError("already recording a demonstration")
        self._reset()
        self.recording = True
        if self._last_state is not None:
            self.start_state, self.t0 = self._last_state, self._last_time

    def stop(self, scenario, source: str = "joystick", meta: Optional[Dict] = None) -> Demonstration:
        if not self.recording and not self.states:
            raise DemonstrationError("not recording: start a demonstration first")
        self.recording = False
        if len(self.states) < self.min_steps or self.start_state is None:
            count = len(self.states)
            self._reset()
            raise DemonstrationError(f"demonstration too short: {count} steps (at least "
                                     f"{self.min_steps} needed); nothing stored")
        meta = dict(meta or {})
        demo = Demonstration(scenario, self.start_state, np.array(self.commands), self.t0,
                             np.array(self.states), source, meta)
        # how far the robot model's rollout strays from what was recorded (0 in the simulator
        # when no step was missed; on a robot: the model's error)
        meta["model_error"] = float(np.abs(demo.rollout()[:, :2] - demo.states[:, :2]).max())
        self._reset()
        return demo
