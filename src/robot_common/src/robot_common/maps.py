"""Occupancy-grid maps in map_server conventions, without ROS.

A `GridMap` stores cells as nav_msgs/OccupancyGrid does: row 0 is the bottom of the map (at the
origin), values 0 (free) .. 100 (occupied) and -1 (unknown). Map files are map_server's
`.yaml` + image pair (PGM), read and written with the same thresholds map_server uses.
"""
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Tuple, Union

import numpy as np
import yaml

from robot_common.errors import MapError

FREE, OCCUPIED, UNKNOWN = 0, 100, -1
PathLike = Union[str, Path]


@dataclass
class GridMap:
    """An occupancy grid: `cells[row, col]`, row 0 at the origin (bottom of the image)."""

    cells: np.ndarray
    resolution: float
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.cells = np.asarray(self.cells, dtype=np.int8)
        if self.cells.ndim != 2 or self.cells.size == 0:
            raise MapError(f"map cells must be a non-empty 2-D array, got shape {self.cells.shape}")
        if not self.resolution > 0:
            raise MapError(f"map resolution must be positive, got {self.resolution}")
        if abs(self.origin[2]) > 1e-9:
            raise MapError(f"rotated map origins are not supported (yaw {self.origin[2]})")

    @property
    def height(self) -> int:
        return self.cells.shape[0]

    @property
    def width(self) -> int:
        return self.cells.shape[1]

    @property
    def size_m(self) -> Tuple[float, float]:
        """(width, height) in metres."""
        return self.width * self.resolution, self.height * self.resolution

    def free_mask(self) -> np.ndarray:
        return self.cells == FREE

    def world_to_cell(self, x, y):
        """(row, col) indices of the cells holding world points (arrays or scalars)."""
        col = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(int)
        row = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(int)
        return row, col

    def cell_to_world(self, row, col):
        """World (x, y) of cell centres."""
        x = self.origin[0] + (np.asarray(col) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(row) + 0.5) * self.resolution
        return x, y

    def inside(self, row, col) -> np.ndarray:
        row, col = np.asarray(row), np.asarray(col)
        return (row >= 0) & (row < self.height) & (col >= 0) & (col < self.width)

    def is_free(self, x, y) -> np.ndarray:
        """True where world points fall in free cells (False outside the map)."""
        row, col = self.world_to_cell(x, y)
        inside = self.inside(row, col)
        result = np.zeros(np.shape(row), dtype=bool)
        result[inside] = self.cells[row[inside], col[inside]] == FREE
        return result

    def downsample(self, factor: int) -> "GridMap":
        """A coarser map: a coarse cell is free only if all its fine cells are free,
        occupied if any is occupied, otherwise unknown."""
        if factor < 1 or int(factor) != factor:
            raise MapError(f"downsample factor must be a positive integer, got {factor}")
        if factor == 1:
            return GridMap(self.cells.copy(), self.resolution, self.origin, dict(self.meta))
        rows, cols = self.height // factor, self.width // factor
        blocks = self.cells[:rows * factor, :cols * factor].reshape(rows, factor, cols, factor)
        coarse = np.full((rows, cols), UNKNOWN, dtype=np.int8)
        coarse[(blocks == FREE).all(axis=(1, 3))] = FREE
        coarse[(blocks == OCCUPIED).any(axis=(1, 3))] = OCCUPIED
        return GridMap(coarse, self.resolution * factor, self.origin, dict(self.meta))


def unmapped(grid: GridMap, points, margin: float) -> np.ndarray:
    """Which of `points` (N, 2) the map does not explain (a mask): free cells all round them,
    every cell within `margin` m (a square). A scan return on or beside a mapped wall - or past a
    wall thinner than `margin` - is the wall, not an obstacle the map lacks."""
    points = np.asarray(points, float).reshape(-1, 2)
    offsets = np.arange(-margin, margin + 1e-9, grid.resolution)
    if offsets[-1] < margin - 1e-9:
        offsets = np.append(offsets, margin)
    lacked = np.ones(len(points), bool)
    for dx in offsets:
        for dy in offsets:
            lacked &= grid.is_free(points[:, 0] + dx, points[:, 1] + dy)
    return lacked


def load_map(yaml_path: PathLike) -> GridMap:
    """Read a map_server map (`.yaml` naming a PGM/PNG image), as map_server's trinary mode does."""
    yaml_path = Path(yaml_path)
    try:
        meta = yaml.safe_load(yaml_path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise MapError(f"cannot read map file {yaml_path}: {err}") from err
    if not isinstance(meta, dict):
        raise MapError(f"map file {yaml_path} is not a YAML mapping")
    missing = [key for key in ("image", "resolution", "origin") if key not in meta]
    if missing:
        raise MapError(f"map file {yaml_path} lacks {', '.join(missing)}")
    image_path = Path(meta["image"])
    if not image_path.is_absolute():
        image_path = yaml_path.parent / image_path
    pixels = _read_grey_image(image_path)
    occupancy = pixels.astype(float) / 255.0 if meta.get("negate", 0) else \
        (255.0 - pixels.astype(float)) / 255.0
    occupied_thresh = float(meta.get("occupied_thresh", 0.65))
    free_thresh = float(meta.get("free_thresh", 0.196))
    cells = np.full(pixels.shape, UNKNOWN, dtype=np.int8)
    cells[occupancy > occupied_thresh] = OCCUPIED
    cells[occupancy < free_thresh] = FREE
    origin = tuple(float(v) for v in meta["origin"])
    return GridMap(np.flipud(cells), float(meta["resolution"]), origin,
                   {"source": str(yaml_path)})


def save_map(grid: GridMap, yaml_path: PathLike) -> Path:
    """Write `grid` as a map_server `.yaml` + `.pgm` pair; returns the yaml path."""
    from PIL import Image

    yaml_path = Path(yaml_path)
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    image_path = yaml_path.with_suffix(".pgm")
    pixels = np.full(grid.cells.shape, 205, dtype=np.uint8)
    pixels[grid.cells == FREE] = 254
    pixels[grid.cells == OCCUPIED] = 0
    Image.fromarray(np.flipud(pixels), mode="L").save(image_path)
    meta = {"image": image_path.name, "resolution": float(grid.resolution),
            "origin": [float(v) for v in grid.origin], "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.196}
    yaml_path.write_text(yaml.safe_dump(meta, default_flow_style=None, sort_keys=False))
    return yaml_path


def _read_grey_image(path: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return np.asarray(image.convert("L"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError) as err:
        raise MapError(f"cannot read map image {path}: {err}") from err


def raycast(grid: GridMap, x: float, y: float, angles: np.ndarray, max_range: float) -> np.ndarray:
    """Ranges from (x, y) along world-frame `angles` to the first occupied or unknown cell.

    Samples each ray at half-cell steps (vectorised over all rays); rays that hit nothing
    return `max_range`. The samples go out in blocks, each only for the rays still open, so the
    cost follows the rays' actual lengths (indoors most stop at a wall within a few metres).
    """
    step = grid.resolution * 0.5
    distances = np.arange(step, max_range + step, step)
    angles = np.asarray(angles, dtype=float)
    cos, sin = np.cos(angles).ravel(), np.sin(angles).ravel()
    ranges = np.full(cos.size, float(max_range))
    open_rays = np.arange(cos.size)
    block = max(int(round(1.0 / step)), 8)           # about a metre of samples at a time
    for start in range(0, distances.size, block):
        if open_rays.size == 0:
            break
        d = distances[start:start + block]
        row, col = grid.world_to_cell(x + cos[open_rays, None] * d, y + sin[open_rays, None] * d)
        inside = grid.inside(row, col)
        blocked = np.ones(row.shape, dtype=bool)
        blocked[inside] = grid.cells[row[inside], col[inside]] != FREE
        hit = blocked.any(axis=1)
        ranges[open_rays[hit]] = d[blocked[hit].argmax(axis=1)]
        open_rays = open_rays[~hit]
    return np.minimum(ranges, max_range).reshape(np.shape(angles))


def ray_disc_hits(x: float, y: float, angles: np.ndarray, centres: np.ndarray,
                  radius: float) -> Tuple[np.ndarray, np.ndarray]:
    """(entry, exit) distances along each ray from (x, y) through the first disc of `radius` at
    `centres` in its way (the nearest entry ahead of the ray's start; inf, inf: none).

    A ray starting inside a disc has a negative entry. Vectorised over rays and discs.
    """
    angles = np.asarray(angles, dtype=float)
    none = np.full(angles.shape, np.inf)
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    if len(centres) == 0:
        return none, none.copy()
    cos, sin = np.cos(angles)[..., None], np.sin(angles)[..., None]
    dx, dy = centres[:, 0] - x, centres[:, 1] - y
    along = dx * cos + dy * sin
    half = np.sqrt(np.maximum(radius ** 2 - (dx * dx + dy * dy - along ** 2), 0.0))
    hit = (along > 0) & (half > 0)
    entry = np.where(hit, along - half, np.inf)
    first = entry.argmin(axis=-1)[..., None]
    nearest = np.take_along_axis(entry, first, axis=-1)[..., 0]
    far = np.take_along_axis(np.where(hit, along + half, np.inf), first, axis=-1)[..., 0]
    return nearest, far


def beam_indices(pose: Tuple[float, float, float], angles: np.ndarray, px, py) -> np.ndarray:
    """Index of the scan beam (sensor-frame `angles`, evenly spaced, from a sensor at `pose`
    x, y, yaw) whose direction holds each world point (px, py); -1 outside the field of view."""
    x, y, yaw = pose
    angles = np.asarray(angles, dtype=float)
    increment = (angles[-1] - angles[0]) / max(len(angles) - 1, 1)
    dx, dy = np.asarray(px, dtype=float) - x, np.asarray(py, dtype=float) - y
    relative = np.mod(np.arctan2(dy, dx) - yaw - angles[0] + increment / 2, 2 * math.pi)
    beam = np.floor(relative / increment).astype(int) if increment > 0 else np.zeros_like(dx, int)
    return np.where((beam >= 0) & (beam < len(angles)), beam, -1)


def beam_reach(ranges, range_min: float, range_max: float) -> np.ndarray:
    """How far each beam of a sensor_msgs/LaserScan saw (REP 117): its range when within
    (range_min, range_max), range_max for no return (+inf, or range_max and beyond), 0 for an
    invalid reading (NaN, -inf, range_min or nearer)."""
    ranges = np.asarray(ranges, float)
    with np.errstate(invalid="ignore"):
        returned = np.isfinite(ranges) & (ranges > range_min) & (ranges < range_max)
        beyond = np.isposinf(ranges) | (np.isfinite(ranges) & (ranges >= range_max))
    return np.where(returned, ranges, np.where(beyond, float(range_max), 0.0))


def seen_through(pose: Tuple[float, float, float], angles: np.ndarray, reach: np.ndarray,
                 points, slack: float = 0.1) -> np.ndarray:
    """Which `points` (N, 2) a scan sees past (move_base's costmaps clear by the same rule): the
    beam whose direction holds the point and the beams either side of it (sensor at `pose` x, y,
    yaw; sensor-frame `angles`, evenly spaced) each reach more than `slack` m beyond it (`reach`:
    how far each beam saw, beam_reach). A point outside the field of view, or behind a return,
    is not seen past."""
    points = np.asarray(points, float).reshape(-1, 2)
    reach = np.asarray(reach, float)
    if not len(points) or not len(reach):
        return np.zeros(len(points), bool)
    beam = beam_indices(pose, angles, points[:, 0], points[:, 1])
    distance = np.hypot(points[:, 0] - pose[0], points[:, 1] - pose[1])
    clear = beam >= 0
    for side in (-1, 0, 1):
        index = np.clip(beam + side, 0, len(reach) - 1)
        clear &= reach[index] > distance + slack
    return clear


def yaw_to_quaternion(yaw: float) -> Tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about z."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
