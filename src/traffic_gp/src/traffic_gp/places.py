"""The places of the training rows, for forecasters that keep a table per place.

`PlaceIndex` snaps points to a square grid of `size` metres (the map's cells when the model is
given them, else 1 cm: rows of a fixed sensor share one place) and numbers the snapped places
the rows visited; `index_at` gives that number for any point, -1 for a place never seen. It
has the face of a `CellGrid` the per-cell baselines need (`n_cells`, `index_at`) and saves as
plain arrays. NumPy only.
"""
from typing import Dict, Optional

import numpy as np

from robot_common.cells import CellGrid

POINT_SIZE = 0.01        # metres: without a map, points within 1 cm are one place
_SHIFT = 2 ** 31


class PlaceIndex:
    """Numbered places of a grid of `size` metres whose cell corners sit at `origin`."""

    def __init__(self, size: float = POINT_SIZE, origin=(-POINT_SIZE / 2, -POINT_SIZE / 2)):
        self.size, self.origin = float(size), (float(origin[0]), float(origin[1]))
        self.keys_ = np.zeros(0, np.int64)

    @classmethod
    def for_cells(cls, cells: Optional[CellGrid]) -> "PlaceIndex":
        """Places are the map's cells (given), else points rounded to 1 cm."""
        if cells is None:
            return cls()
        return cls(cells.cell_size, (float(cells.coarse.origin[0]), float(cells.coarse.origin[1])))

    def _keys(self, x, y) -> np.ndarray:
        col = np.floor((np.asarray(x, float) - self.origin[0]) / self.size).astype(np.int64)
        row = np.floor((np.asarray(y, float) - self.origin[1]) / self.size).astype(np.int64)
        return (col + _SHIFT // 2) * _SHIFT + (row + _SHIFT // 2)

    def fit(self, x, y) -> "PlaceIndex":
        self.keys_ = np.unique(self._keys(x, y).ravel())
        return self

    def add(self, x, y) -> "PlaceIndex":
        """Add the places of more rows (places already known keep their number)."""
        new = np.setdiff1d(np.unique(self._keys(x, y).ravel()), self.keys_)
        if new.size:
            self.keys_ = np.concatenate([self.keys_, new])
        return self

    @property
    def n_cells(self) -> int:
        return int(self.keys_.size)

    def index_at(self, x, y) -> np.ndarray:
        keys = self._keys(x, y)
        if self.keys_.size == 0:
            return np.full(keys.shape, -1, np.int64)
        order = np.argsort(self.keys_, kind="stable")
        sorted_keys = self.keys_[order]
        pos = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
        return np.where(sorted_keys[pos] == keys, order[pos], -1).astype(np.int64)

    def to_arrays(self) -> Dict[str, np.ndarray]:
        return {"size": np.array(self.size), "origin": np.array(self.origin),
                "keys": self.keys_}

    @classmethod
    def from_arrays(cls, arrays: Dict[str, np.ndarray]) -> "PlaceIndex":
        index = cls(float(arrays["size"]), tuple(np.asarray(arrays["origin"], float)))
        index.keys_ = np.asarray(arrays["keys"], np.int64)
        return index
