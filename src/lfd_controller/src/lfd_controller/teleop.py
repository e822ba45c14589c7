"""Joystick to velocity commands with a dead-man button, and recording buttons (no ROS).

Default mapping: an Xbox 360 pad under the Linux `joy` driver (xpad): left stick up/down
(axis 1) drives, left stick left/right (axis 0) turns, LB (button 4) must be held to move, A
(button 0) starts recording a demonstration, B (button 1) stops it.
"""
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

from lfd_controller.errors import LfdError

XBOX360 = {"axis_linear": 1, "axis_angular": 0, "enable_button": 4, "record_start_button": 0,
           "record_stop_button": 1}


@dataclass
class JoyMapping:
    """Axis scaling and buttons (indices into sensor_msgs/Joy axes and buttons)."""

    axis_linear: int = XBOX360["axis_linear"]
    axis_angular: int = XBOX360["axis_angular"]
    scale_linear: float = 0.5
    scale_angular: float = 1.5
    deadzone: float = 0.05
    enable_button: int = XBOX360["enable_button"]
    record_start_button: int = XBOX360["record_start_button"]
    record_stop_button: int = XBOX360["record_stop_button"]

    def __post_init__(self):
        for name in ("axis_linear", "axis_angular", "enable_button", "record_start_button",
                     "record_stop_button"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < -1:
                raise LfdError(f"joystick mapping: {name} must be an index >= 0 (or -1: none), "
                               f"got {value!r}")
        if not 0.0 <= self.deadzone < 1.0:
            raise LfdError(f"joystick mapping: deadzone must be in [0, 1), got {self.deadzone!r}")


def _axis(axes: Sequence[float], index: int, deadzone: float) -> float:
    if index < 0 or index >= len(axes):
        return 0.0
    value = max(-1.0, min(1.0, float(axes[index])))
    if abs(value) <= deadzone:
        return 0.0
    return (abs(value) - deadzone) / (1.0 - deadzone) * (1.0 if value > 0 else -1.0)


def _pressed(buttons: Sequence[int], index: int) -> bool:
    return 0 <= index < len(buttons) and bool(buttons[index])


class JoyTeleop:
    """Turns joystick states into (linear, angular) commands and recording events.

    `update(axes, buttons)` returns (command or None, events): the command while the dead-man
    button is held, one zero command when it is released (so the robot stops), None otherwise;
    events are "start" / "stop" on a recording button's press (not while it stays pressed).
    """

    def __init__(self, mapping: Optional[JoyMapping] = None):
        self.mapping = mapping or JoyMapping()
        self._enabled = False
        self._previous: List[int] = []

    def update(self, axes: Sequence[float], buttons: Sequence[int]
               ) -> Tuple[Optional[Tuple[float, float]], List[str]]:
        mapping = self.mapping
        events = []
        for name, index in (("start", mapping.record_start_button), ("stop", mapping.record_stop_button)):
            if _pressed(buttons, index) and not _pressed(self._previous, index):
                events.append(name)
        self._previous = list(buttons)
        if _pressed(buttons, mapping.enable_button):
            self._enabled = True
            return (mapping.scale_linear * _axis(axes, mapping.axis_linear, mapping.deadzone),
                    mapping.scale_angular * _axis(axes, mapping.axis_angular, mapping.deadzone)), events
        if self._enabled:
            self._enabled = False
            return (0.0, 0.0), events
        return None, events

    def axes_for(self, linear: float, angular: float, count: int = 8) -> List[float]:
        """Joystick axes that produce (linear, angular): what a person would push (for tests and
        synthetic teleoperation)."""
        mapping = self.mapping
        axes = [0.0] * count
        for index, value, scale in ((mapping.axis_linear, linear, mapping.scale_linear),
                                    (mapping.axis_angular, angular, mapping.scale_angular)):
            fraction = max(-1.0, min(1.0, value / scale))
            if fraction:
                magnitude = mapping.deadzone + abs(fraction) * (1.0 - mapping.deadzone)
                axes[index] = magnitude if fraction > 0 else -magnitude
        return axes
