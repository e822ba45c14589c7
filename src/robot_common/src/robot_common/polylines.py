"""Paths as polylines (N, 2 points in the map frame; no ROS): arc lengths, the point of a path
nearest a position, distances to a path. The hallway controller and the errand server measure
progress along a path and compare a re-plan with the path before it with these."""
from typing import Tuple

import numpy as np

__all__ = ["arc_lengths", "path_length", "nearest_arc", "points_along", "point_at", "distance_to", "same_way"]


def arc_lengths(path) -> np.ndarray:
    """Arc length (m) at each point of `path` (N, 2), starting at 0."""
    path = np.asarray(path, float).reshape(-1, 2)
    steps = np.hypot(*np.diff(path, axis=0).T) if len(path) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(steps)])


def path_length(path) -> float:
    """Length (m) of a polyline (N, 2); 0 for fewer than two points."""
    return float(arc_lengths(path)[-1])


def _segments(path: np.ndarray, points: np.ndarray):
    """For each of `points` (M, 2) and each segment of `path`: the fraction along the segment of
    the segment's point nearest it, and the distance to that point ((M, K) each)."""
    start, span = path[:-1], np.diff(path, axis=0)
    length2 = np.maximum((span ** 2).sum(axis=1), 1e-12)
    offset = points[:, None, :] - start[None]
    along = np.clip((offset * span[None]).sum(axis=2) / length2, 0.0, 1.0)
    gaps = np.hypot(*np.moveaxis(offset - along[..., None] * span[None], 2, 0))
    return along, gaps


def nearest_arc(path, position) -> Tuple[float, float]:
    """(arc length, distance) of the point of `path` nearest `position` (the first such point
    where several are as near)."""
    path = np.asarray(path, float).reshape(-1, 2)
    position = np.asarray(position, float)[:2]
    if len(path) < 2:
        return 0.0, float(np.hypot(*(path[0] - position)))
    along, gaps = _segments(path, position[None])
    k = int(np.argmin(gaps[0]))
    arc = arc_lengths(path)
    return float(arc[k] + along[0, k] * (arc[k + 1] - arc[k])), float(gaps[0, k])


def points_along(path, distances, arcs=None) -> np.ndarray:
    """Points (len(distances), 2) at these arc lengths along `path` (clipped to its ends);
    `arcs`: its arc_lengths, when known."""
    path = np.asarray(path, float).reshape(-1, 2)
    arcs = arc_lengths(path) if arcs is None else arcs
    distances = np.clip(np.asarray(distances, float), 0.0, arcs[-1])
    return np.column_stack([np.interp(distances, arcs, path[:, i]) for i in (0, 1)])


def point_at(path, arc: float, arcs=None) -> np.ndarray:
    """The point `arc` m along `path` (clipped to its ends); `arcs`: its arc_lengths, when known."""
    return points_along(path, [arc], arcs)[0]


def distance_to(path, points) -> np.ndarray:
    """Distance (m) from each of `points` (M, 2) to the nearest point of `path`."""
    path = np.asarray(path, float).reshape(-1, 2)
    points = np.asarray(points, float).reshape(-1, 2)
    if len(path) < 2:
        return np.hypot(*(points - path[0]).T)
    return _segments(path, points)[1].min(axis=1)


def same_way(old, new, position, *, ahead: float, tolerance: float = 0.5,
             step: float = 0.25) -> bool:
    """Whether path `new` goes the way of path `old` from `position` (a re-plan of the same
    route rather than a route elsewhere): every point of `new` from its point nearest
    `position` to `ahead` m on lies within `tolerance` m - plus however far `position` itself is
    off `old` (a robot beside its path, a plan that starts at the robot) - of what is left of
    `old` from 1 m before its point nearest `position`, and does not run back along it."""
    old = np.asarray(old, float).reshape(-1, 2)
    new = np.asarray(new, float).reshape(-1, 2)
    start, off = nearest_arc(old, position)
    arcs = arc_lengths(old)
    keep = arcs > start - 1.0
    rest = np.vstack([point_at(old, start - 1.0, arcs)[None], old[keep]])
    from_here, new_arcs = nearest_arc(new, position)[0], arc_lengths(new)
    samples = points_along(new, from_here + np.arange(0.0, ahead + 1e-9, step), new_arcs)
    if not np.all(distance_to(rest, samples) <= tolerance + off):
        return False
    # and in the same direction: not back along the stretch behind the robot
    return nearest_arc(rest, samples[-1])[0] >= nearest_arc(rest, samples[0])[0] - tolerance
