"""Drawing geometry for clusters: covariance ellipses and class colours (pure; no rospy)."""
import colorsys
import math
import zlib
from typing import Mapping, Optional, Tuple

import numpy as np

__all__ = ["ellipse", "class_colour"]


def ellipse(covariance, n_sigma: float = 2.0) -> Tuple[float, float, float]:
    """(major diameter, minor diameter, yaw of the major axis) of the n-sigma ellipse of the
    x/y block of a covariance matrix."""
    cov = np.asarray(covariance, dtype=float)[:2, :2]
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    values = np.clip(values, 0.0, None)
    major = vectors[:, 1]
    yaw = math.atan2(major[1], major[0])
    return 2 * n_sigma * math.sqrt(values[1]), 2 * n_sigma * math.sqrt(values[0]), yaw


def class_colour(class_name: str, overrides: Optional[Mapping[str, Tuple[float, float, float]]] = None
                 ) -> Tuple[float, float, float]:
    """A saturated colour for a class, the same in every run (a hue from a hash of the name)."""
    if overrides and class_name in overrides:
        return tuple(overrides[class_name])
    code = zlib.crc32(class_name.encode())
    hue = (code % 360) / 360.0
    value = 0.85 + 0.15 * ((code >> 9) % 2)
    return colorsys.hsv_to_rgb(hue, 0.85, value)
