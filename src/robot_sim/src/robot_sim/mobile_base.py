"""A mobile base patrolling a closed path, and the sensor readings it would make (no ROS).

Poses are a pure function of time, so recordings of the simulated topics can be checked against
the truth. Readings: planar pose and velocity (odometry), a laser scan ray-cast in the map, a
camera image whose content moves with the robot, and the two wheel joint angles.
"""
import math
from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np

from robot_common.maps import GridMap, raycast
from robot_sim.building import Building


@dataclass(frozen=True)
class BaseState:
    x: float
    y: float
    yaw: float
    linear: float
    angular: float


class PatrolPath:
    """Constant-speed motion along a closed polyline of waypoints."""

    def __init__(self, waypoints: Sequence[Tuple[float, float]], speed: float):
        points = np.asarray(waypoints, dtype=float)
        if points.ndim != 2 or points.shape[0] < 2 or points.shape[1] != 2:
            raise ValueError("a patrol path needs at least two (x, y) waypoints")
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        self.points = np.vstack([points, points[:1]])
        segments = np.diff(self.points, axis=0)
        self.lengths = np.hypot(segments[:, 0], segments[:, 1])
        if not (self.lengths > 0).all():
            raise ValueError("consecutive patrol waypoints must differ")
        self.cumulative = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.headings = np.arctan2(segments[:, 1], segments[:, 0])
        self.speed = speed

    @property
    def period(self) -> float:
        return float(self.cumulative[-1] / self.speed)

    def state(self, t: float) -> BaseState:
        distance = (t * self.speed) % self.cumulative[-1]
        index = int(np.searchsorted(self.cumulative, distance, side="right") - 1)
        index = min(index, len(self.lengths) - 1)
        fraction = (distance - self.cumulative[index]) / self.lengths[index]
        x, y = self.points[index] + fraction * (self.points[index + 1] - self.points[index])
        return BaseState(float(x), float(y), float(self.headings[index]), self.speed, 0.0)


def hall_patrol(building: Building, speed: float = 0.5) -> PatrolPath:
    """A loop along the main hall's centre line, turning in the back hall."""
    main = next(area for area in building.halls if area.name == "main_hall")
    y = (main.box[1] + main.box[3]) / 2.0
    x0, x1 = main.box[0] + 1.0, main.box[2] + 0.5
    return PatrolPath([(x0, y - 0.5), (x1, y - 0.5), (x1, y + 0.5), (x0, y + 0.5)], speed)


class SensorModel:
    """Readings of a laser scanner, a camera and two wheel encoders on the patrolling base."""

    def __init__(self, grid: GridMap, *, scan_beams: int = 360, scan_range: float = 10.0,
                 image_width: int = 320, image_height: int = 240, wheel_radius: float = 0.035,
                 wheel_separation: float = 0.23):
        if scan_beams < 2:
            raise ValueError(f"scan_beams must be at least 2, got {scan_beams}")
        self.grid = grid
        self.scan_range = scan_range
        self.scan_angles = np.linspace(-math.pi * 0.75, math.pi * 0.75, scan_beams)
        self.wheel_radius = wheel_radius
        self.wheel_separation = wheel_separation
        rows = np.linspace(0, 255, image_height, dtype=np.float32)[:, None]
        cols = np.linspace(0, 255, image_width, dtype=np.float32)[None, :]
        self._base_image = np.stack([np.broadcast_to(cols, (image_height, image_width)),
                                     np.broadcast_to(rows, (image_height, image_width)),
                                     np.full((image_height, image_width), 96, np.float32)],
                                    axis=-1).astype(np.uint8)

    @property
    def scan_increment(self) -> float:
        return float(self.scan_angles[1] - self.scan_angles[0])

    def scan(self, state: BaseState) -> np.ndarray:
        return raycast(self.grid, state.x, state.y, state.yaw + self.scan_angles, self.scan_range)

    def image(self, state: BaseState) -> np.ndarray:
        """An rgb8 image (height, width, 3) whose pattern shifts with the robot's position."""
        shift = int((state.x + state.y) * 40) % self._base_image.shape[1]
        return np.roll(self._base_image, shift, axis=1)

    def wheel_angles(self, t: float, state: BaseState) -> List[float]:
        """Left and right wheel angles (rad) after driving at `state`'s speeds for `t` seconds."""
        left = (state.linear - state.angular * self.wheel_separation / 2) / self.wheel_radius
        right = (state.linear + state.angular * self.wheel_separation / 2) / self.wheel_radius
        return [left * t, right * t]
