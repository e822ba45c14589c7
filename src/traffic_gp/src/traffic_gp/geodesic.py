"""Map-aware spatial inputs: free cells placed so that straight-line distances between them
approximate distances through free space (walking distances), not through walls.

`GeodesicEmbedding.from_cells` takes the free cells of a `CellGrid`, computes shortest paths on
their 8-neighbour graph (steps of one cell, diagonals sqrt(2) cells; scipy.sparse.csgraph) from
`n_landmarks` landmark cells chosen farthest-first, and places every cell by landmark MDS
(de Silva and Tenenbaum 2004: classical MDS of the landmarks' distances, every other cell
triangulated from its distances to the landmarks; O(cells x landmarks)). The result has `dims`
coordinates per cell, in metres. Two cells on either side of a wall are as far apart as the
walk between them, so a stationary kernel on these coordinates does not carry a busy hall's
rate into the room behind its wall. Separate components of the free space (no path between
them) are set `gap` metres beyond the largest finite distance apart.

Reachability: `component` labels each free cell's connected part of the free space and
`observed` marks the parts holding a training row (`mark_observed`). A part no observed place
connects to is a place people cannot walk to from anywhere the robots watched (a room whose
door the map shows closed): the crowd model predicts nobody there (`unreachable`) instead of
its prior, which far from the data is about the average rate of the observed halls.

The embedding is plain arrays (`to_arrays` / `from_arrays`): a saved crowd model keeps it and
predicts the same after loading, without the map. Points off the free cells (walls, unknown,
outside the grid) take the coordinates of the nearest free cell.
"""
from typing import Dict, Optional

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from traffic_gp.errors import ModelFormatError

DEFAULT_DIMS = 6
DEFAULT_LANDMARKS = 48
ARRAY_NAMES = ("coords", "nearest", "grid", "component", "observed")


def _index_image(cells: CellGrid) -> np.ndarray:
    """Free-cell index per coarse grid cell, -1 elsewhere."""
    index = np.full(cells.shape, -1, dtype=np.int64)
    index[cells.rows, cells.cols] = np.arange(cells.n_cells)
    return index


def free_space_graph(cells: CellGrid) -> sparse.csr_matrix:
    """The free cells' 8-neighbour graph, edge weights in metres (diagonals only where both
    side cells are free: no corner cutting through a wall's end)."""
    index = _index_image(cells)
    rows, cols = index.shape
    size = cells.cell_size
    sources, targets, weights = [], [], []
    padded = np.pad(index, 1, constant_values=-1)
    for d_row, d_col in ((0, 1), (1, 0), (1, 1), (1, -1)):
        here = padded[1:rows + 1, 1:cols + 1]
        there = padded[1 + d_row:rows + 1 + d_row, 1 + d_col:cols + 1 + d_col]
        ok = (here >= 0) & (there >= 0)
        if d_row and d_col:                    # diagonal: both cells beside the step free
            side_a = padded[1 + d_row:rows + 1 + d_row, 1:cols + 1]
            side_b = padded[1:rows + 1, 1 + d_col:cols + 1 + d_col]
            ok &= (side_a >= 0) & (side_b >= 0)
        sources.append(here[ok])
        targets.append(there[ok])
        weights.append(np.full(int(ok.sum()), size * np.hypot(d_row, d_col)))
    source, target = np.concatenate(sources), np.concatenate(targets)
    weight = np.concatenate(weights)
    n = cells.n_cells
    graph = sparse.coo_matrix((weight, (source, target)), shape=(n, n)).tocsr()
    return graph.maximum(graph.T)


def geodesic_distances(cells: CellGrid, sources) -> np.ndarray:
    """Distances through free space (metres) from the free cells `sources` to every free cell;
    shape (len(sources), n_cells), inf where no path exists."""
    return csgraph.dijkstra(free_space_graph(cells), directed=False,
                            indices=np.atleast_1d(np.asarray(sources, dtype=np.int64)))


class GeodesicEmbedding:
    """Coordinates of a cell grid's free cells whose distances approximate walking distances.

    Attributes: `coords` (n_cells x dims, metres), `nearest` (per coarse grid cell, the index of
    the nearest free cell), `grid` ([origin x, origin y, resolution]), `component` (per cell,
    its connected part of the free space) and `observed` (per part: holds a training row).
    """

    def __init__(self, coords: np.ndarray, nearest: np.ndarray, grid: np.ndarray,
                 component: np.ndarray, observed: Optional[np.ndarray] = None):
        self.coords = np.asarray(coords, dtype=float)
        self.nearest = np.asarray(nearest, dtype=np.int64)
        self.grid = np.asarray(grid, dtype=float).ravel()
        self.component = np.asarray(component, dtype=np.int64).ravel()
        n_parts = int(self.component.max()) + 1 if self.component.size else 0
        self.observed = np.zeros(n_parts, dtype=bool) if observed is None \
            else np.asarray(observed, dtype=bool).ravel()
        if (self.coords.ndim != 2 or self.nearest.ndim != 2 or self.grid.size != 3
                or self.nearest.size == 0 or self.nearest.min() < 0
                or self.nearest.max() >= len(self.coords)
                or self.component.size != len(self.coords) or self.component.min() < 0
                or self.observed.size != n_parts):
            raise ModelFormatError("inconsistent geodesic embedding arrays")

    @property
    def dims(self) -> int:
        return int(self.coords.shape[1])

    @classmethod
    def from_cells(cls, cells: CellGrid, *, dims: int = DEFAULT_DIMS,
                   n_landmarks: int = DEFAULT_LANDMARKS, gap: float = 10.0,
                   seed: int = 0) -> "GeodesicEmbedding":
        """Landmark MDS of the distances through the free cells of `cells` (module docstring)."""
        if dims < 1 or n_landmarks < 2:
            raise ConfigError(f"geodesic embedding needs dims >= 1 and n_landmarks >= 2, got "
                              f"{dims} and {n_landmarks}")
        graph = free_space_graph(cells)
        n = cells.n_cells
        n_landmarks = min(n_landmarks, n)
        landmarks = [int(np.random.default_rng(seed).integers(n))]
        dist = np.empty((n_landmarks, n))
        nearest_landmark = np.full(n, np.inf)
        for i in range(n_landmarks):            # farthest-first: unreached components first
            dist[i] = csgraph.dijkstra(graph, directed=False, indices=landmarks[i])
            nearest_landmark = np.minimum(nearest_landmark, dist[i])
            if i + 1 < n_landmarks:
                landmarks.append(int(np.argmax(nearest_landmark)))
        finite = np.isfinite(dist)
        dist[~finite] = (dist[finite].max() if finite.any() else 0.0) + gap
        coords = _landmark_mds(dist, np.asarray(landmarks), dims)
        _, component = csgraph.connected_components(graph, directed=False)
        index = _index_image(cells)
        _, (near_row, near_col) = ndimage.distance_transform_edt(index < 0, return_indices=True)
        nearest = index[near_row, near_col]
        coarse = cells.coarse
        return cls(coords, nearest, [coarse.origin[0], coarse.origin[1], coarse.resolution],
                   component)

    def cell_of(self, x, y) -> np.ndarray:
        """Index of the free cell holding (or nearest to) each point."""
        x0, y0, resolution = self.grid
        rows, cols = self.nearest.shape
        col = np.clip(np.floor((np.asarray(x, float) - x0) / resolution).astype(int), 0, cols - 1)
        row = np.clip(np.floor((np.asarray(y, float) - y0) / resolution).astype(int), 0, rows - 1)
        return self.nearest[row, col]

    def transform(self, x, y) -> np.ndarray:
        """Embedded coordinates (len(x) x dims) of points (x, y)."""
        return self.coords[self.cell_of(np.ravel(x), np.ravel(y))]

    def mark_observed(self, x, y) -> None:
        """The parts of the free space holding the places (x, y) have been watched."""
        if np.size(x):
            self.observed[np.unique(self.component[self.cell_of(np.ravel(x), np.ravel(y))])] = True

    def unreachable(self, x, y) -> np.ndarray:
        """True for places in a part of the free space that no watched place connects to."""
        return ~self.observed[self.component[self.cell_of(np.ravel(x), np.ravel(y))]]

    def to_arrays(self) -> Dict[str, np.ndarray]:
        return {"coords": self.coords, "nearest": self.nearest, "grid": self.grid,
                "component": self.component, "observed": self.observed}

    @classmethod
    def from_arrays(cls, arrays: Optional[Dict[str, np.ndarray]]) -> Optional["GeodesicEmbedding"]:
        """The embedding saved by `to_arrays`, or None when `arrays` is empty."""
        if not arrays:
            return None
        missing = [name for name in ARRAY_NAMES if name not in arrays]
        if missing:
            raise ModelFormatError(f"saved geodesic embedding lacks {missing}")
        return cls(*(arrays[name] for name in ARRAY_NAMES))


def _landmark_mds(dist: np.ndarray, landmarks: np.ndarray, dims: int) -> np.ndarray:
    """Landmark MDS: classical MDS of the landmarks' squared distances, then every point placed
    from its squared distances to the landmarks (distance-based triangulation)."""
    squared = dist ** 2                                   # (landmarks, points)
    landmark_sq = squared[:, landmarks]
    landmark_sq = 0.5 * (landmark_sq + landmark_sq.T)
    k = len(landmarks)
    centring = np.eye(k) - np.full((k, k), 1.0 / k)
    gram = -0.5 * centring @ landmark_sq @ centring
    values, vectors = np.linalg.eigh(gram)
    order = np.argsort(values)[::-1][:dims]
    values, vectors = values[order], vectors[:, order]
    keep = values > 1e-9 * max(values[0], 1e-12)
    pseudo = np.zeros((dims, k))
    pseudo[keep] = (vectors[:, keep] / np.sqrt(values[keep])).T
    mean_sq = landmark_sq.mean(axis=1)
    return (-0.5 * pseudo @ (squared - mean_sq[:, None])).T
