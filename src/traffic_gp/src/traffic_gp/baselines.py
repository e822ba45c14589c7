"""Baselines for the crowd model, per cell: the mean per time bin, and FreMEn.

Both estimate a people density per cell (counts / exposure) and predict point rates (their
predictive distribution is Poisson). Rates are floored at `floor` x the global mean density so
that held-out log-likelihoods stay finite.

FreMEn (Krajnik et al., "FreMEn: Frequency Map Enhancement for Long-Term Mobile Robot Autonomy
in Changing Environments", IEEE T-RO 33(4), 2017) models each cell's state over time as its mean
plus the `order` most prominent harmonic components among the periods T/k (k = 1..K, T the
longest period, the shortest `shortest_period`). The spectrum is computed from the irregularly
timed observations as the FreMEn implementation does, with running sums of state x cos/sin and
of the sampling "balance" cos/sin, so that uneven sampling does not fake periodicities; here each
observation is weighted by its exposure (state = count / exposure).
"""
from typing import Dict, Optional

import numpy as np
from scipy import sparse

import traffic_gp.predictive as predictive
from robot_common.cells import CellGrid
from robot_common.errors import ConfigError
from traffic_gp.errors import NotFittedError
from traffic_gp.observations import Observations


class _CellBaseline:
    def __init__(self, cells: CellGrid, *, period: float = 24.0, floor: float = 1e-3):
        self.cells, self.period, self.floor = cells, period, floor

    def _cell_index(self, x, y) -> np.ndarray:
        return self.cells.index_at(x, y)

    def _check_fitted(self) -> None:
        if not hasattr(self, "global_rate_"):
            raise NotFittedError(f"{type(self).__name__} is not fitted yet")

    def predict(self, x, y, t, exposure=1.0) -> np.ndarray:
        """Expected counts (densities for exposure 1)."""
        self._check_fitted()
        x, y, t = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, y, t)))
        rate = self._rate(self._cell_index(x.ravel(), y.ravel()), np.mod(t.ravel(), self.period))
        rate = np.maximum(rate, self.floor * self.global_rate_).reshape(x.shape)
        return np.asarray(exposure) * rate

    def score(self, obs: Observations) -> float:
        """Mean held-out Poisson log-likelihood of the counts (higher is better)."""
        mean = np.log(self.predict(obs.x, obs.y, obs.t))
        return float(np.mean(predictive.log_density(obs.count, mean, 0.0, obs.exposure)))

    def to_arrays(self) -> Dict[str, np.ndarray]:
        """The fitted state as plain arrays (`from_arrays` restores it with the same cells)."""
        self._check_fitted()
        arrays = {name: np.asarray(getattr(self, name)) for name in self._STATE}
        arrays.update(kind=np.array(type(self).__name__), period=np.array(self.period),
                      floor=np.array(self.floor))
        return arrays

    @staticmethod
    def from_arrays(arrays: Dict[str, np.ndarray], cells) -> "_CellBaseline":
        """A fitted BinnedMean or FreMEn from `to_arrays`, predicting over `cells`."""
        kind = str(arrays["kind"])
        classes = {"BinnedMean": BinnedMean, "FreMEn": FreMEn}
        if kind not in classes:
            raise ConfigError(f"unknown baseline kind {kind!r}")
        model = classes[kind].__new__(classes[kind])
        _CellBaseline.__init__(model, cells, period=float(arrays["period"]),
                               floor=float(arrays["floor"]))
        for name in model._STATE:
            value = np.asarray(arrays[name])
            setattr(model, name, value.item() if value.ndim == 0 else value)
        if isinstance(model, FreMEn):           # what only fitting needs
            model.shortest_period, model.chunk = None, 200000
        return model


class BinnedMean(_CellBaseline):
    """Counts / exposure per cell and time bin of `bin_minutes`; empty bins fall back to the
    cell's mean, unseen cells to the global mean."""

    _STATE = ("global_rate_", "rate_", "bin_minutes")

    def __init__(self, cells: CellGrid, *, bin_minutes: float = 10.0, period: float = 24.0,
                 floor: float = 1e-3):
        super().__init__(cells, period=period, floor=floor)
        if not bin_minutes > 0:
            raise ConfigError(f"bin_minutes must be positive, got {bin_minutes}")
        self.bin_minutes = bin_minutes

    def _bins(self, t) -> np.ndarray:
        n_bins = int(np.ceil(self.period * 60.0 / self.bin_minutes))
        return np.minimum((np.mod(t, self.period) * 60.0 / self.bin_minutes).astype(int), n_bins - 1)

    def fit(self, obs: Observations) -> "BinnedMean":
        n_bins = int(np.ceil(self.period * 60.0 / self.bin_minutes))
        self._sums = (np.zeros((0, n_bins)), np.zeros((0, n_bins)), 0.0, 0.0)
        return self.update(obs)

    def update(self, obs: Observations) -> "BinnedMean":
        """Add rows to a model fitted in this process (its sums; cells may have been added)."""
        counts, expo, total_count, total_expo = self._sums
        n_cells = self.cells.n_cells
        counts, expo = (np.pad(a, ((0, n_cells - a.shape[0]), (0, 0))) for a in (counts, expo))
        cell = self._cell_index(obs.x, obs.y)
        ok = cell >= 0
        key = np.ravel_multi_index((cell[ok], self._bins(obs.t[ok])), counts.shape)
        counts = counts + np.bincount(key, obs.count[ok], counts.size).reshape(counts.shape)
        expo = expo + np.bincount(key, obs.exposure[ok], expo.size).reshape(expo.shape)
        self._sums = (counts, expo, total_count + obs.count.sum(), total_expo + obs.exposure.sum())
        self.global_rate_ = max(self._sums[2], 0.5) / max(self._sums[3], 1e-12)
        cell_rate = np.where(expo.sum(1) > 0, counts.sum(1) / np.maximum(expo.sum(1), 1e-12),
                             self.global_rate_)
        self.rate_ = np.where(expo > 0, counts / np.maximum(expo, 1e-12), cell_rate[:, None])
        return self

    def _rate(self, cell, t) -> np.ndarray:
        rate = np.full(cell.shape, self.global_rate_)
        ok = cell >= 0
        rate[ok] = self.rate_[cell[ok], self._bins(t[ok])]
        return rate


class FreMEn(_CellBaseline):
    """Per-cell mean + `order` strongest harmonics of periods `period`/k down to `shortest_period`."""

    _STATE = ("global_rate_", "mean_", "omega_", "amplitude_", "phase_", "order")

    def __init__(self, cells: CellGrid, *, order: int = 3, period: float = 24.0,
                 shortest_period: Optional[float] = 1.0 / 6.0, floor: float = 1e-3,
                 chunk: int = 200000):
        super().__init__(cells, period=period, floor=floor)
        if order < 0 or int(order) != order:
            raise ConfigError(f"order must be a non-negative integer, got {order}")
        if not period > 0:
            raise ConfigError(f"period must be positive, got {period}")
        self.order, self.shortest_period, self.chunk = int(order), shortest_period, chunk

    @property
    def omegas(self) -> np.ndarray:
        n = int(round(self.period / (self.shortest_period or self.period / 24.0)))
        return 2.0 * np.pi * np.arange(1, n + 1) / self.period

    def fit(self, obs: Observations) -> "FreMEn":
        size = self.omegas.size
        self._sums = (np.zeros(0), np.zeros(0), np.zeros((0, size), complex),
                      np.zeros((0, size), complex), 0.0, 0.0)
        return self.update(obs)

    def update(self, obs: Observations) -> "FreMEn":
        """Add rows to a model fitted in this process (its running sums; cells may have been
        added); the order stays."""
        n_cells, omegas = self.cells.n_cells, self.omegas
        expo, counts, states, balance, total_count, total_expo = self._sums
        grow = n_cells - expo.size
        expo, counts = np.pad(expo, (0, grow)), np.pad(counts, (0, grow))
        states, balance = (np.pad(a, ((0, grow), (0, 0))) for a in (states, balance))
        cell = self._cell_index(obs.x, obs.y)
        ok = np.nonzero(cell >= 0)[0]
        expo = expo + np.bincount(cell[ok], obs.exposure[ok], n_cells)
        counts = counts + np.bincount(cell[ok], obs.count[ok], n_cells)
        total_count, total_expo = total_count + obs.count.sum(), total_expo + obs.exposure.sum()
        self.global_rate_ = max(total_count, 0.5) / max(total_expo, 1e-12)
        self.mean_ = np.where(expo > 0, counts / np.maximum(expo, 1e-12), self.global_rate_)
        # Running sums per cell and frequency: sum n e^{-iwt} and the balance sum e e^{-iwt}.
        for start in range(0, ok.size, self.chunk):
            rows = ok[start:start + self.chunk]
            phase = np.exp(-1j * np.outer(obs.t[rows], omegas))
            member = sparse.csr_matrix((np.ones(rows.size), (cell[rows], np.arange(rows.size))),
                                       shape=(n_cells, rows.size))
            states += member @ (obs.count[rows, None] * phase)
            balance += member @ (obs.exposure[rows, None] * phase)
        self._sums = (expo, counts, states, balance, total_count, total_expo)
        self.spectrum_ = (states - self.mean_[:, None] * balance) / np.maximum(expo, 1e-12)[:, None]
        return self.set_order(self.order)

    def set_order(self, order: int) -> "FreMEn":
        """Keep the `order` strongest components of the fitted spectrum (no refit needed)."""
        if order < 0 or int(order) != order:
            raise ConfigError(f"order must be a non-negative integer, got {order}")
        self.order = int(order)
        strongest = np.argsort(-np.abs(self.spectrum_), axis=1)[:, :self.order]
        self.omega_ = self.omegas[strongest]                               # (cells, order)
        picked = np.take_along_axis(self.spectrum_, strongest, axis=1)
        self.amplitude_ = 2.0 * np.abs(picked)
        self.phase_ = np.angle(picked)
        return self

    def _rate(self, cell, t) -> np.ndarray:
        rate = np.full(cell.shape, self.global_rate_)
        ok = cell >= 0
        c = cell[ok]
        waves = self.amplitude_[c] * np.cos(self.omega_[c] * t[ok, None] + self.phase_[c])
        rate[ok] = self.mean_[c] + waves.sum(axis=1)
        return rate
