"""Incremental Gaussian mixture model (IGMM) of any dimension, in its fast form.

Engel and Heinen (2010), with the precision-matrix form of Pinto and Engel (2015):

- novelty: x starts a new component (mean x, covariance sigma_ini^2 I, age v = 1, support sp = 1)
  when its squared Mahalanobis distance to every component exceeds -2 ln(novelty_constant);
- otherwise every component j gets the posterior p(j|x) (in log space), v_j += 1,
  sp_j += p(j|x), omega = p(j|x) / sp_j and the *exact* weighted moment update
  mu <- mu + omega e,  C <- (1 - omega) (C + omega e e^T)   with e = x - mu (old mean).
  (The update usually published, C <- (1-omega) C + omega e* e*^T - dmu dmu^T, can make C
  indefinite; this one is a convex combination of positive definite terms.)
- a component is pruned when v_j > v_min and sp_j < sp_min.

Precision matrices and log-determinants are kept up to date with rank-one updates
(Sherman-Morrison, matrix determinant lemma), so an update costs O(K D^2), not O(K D^3); every
`refresh_interval` updates they are recomputed from the covariances to stop round-off drift.
Components whose posterior is below 1e-12 of the best one are skipped (their update would be
below round-off), and ages are kept as birth counters, so most updates touch one component.

Beyond the original: sample weights (detection confidences) multiply the posterior;
`measurement_cov` (e.g. an object's extent) enters as C <- (1-omega)(C + omega e e^T) + omega R
and widens new components; every component keeps the times of the observations it was the most
likely source of (first/last seen, counts in a time window).

Batch mode (`batch=True`): the model is a function of the *multiset* of rows given since the last
`fit`, restore or `consolidate()`: the rows are kept, and every `partial_fit` call relearns all of
them, starting from the state at that point, in one canonical pseudo-random order (sorted by a hash
of each row's values). So the same data fed in any row order and split into any chunks over any
number of calls gives a bit-identical model (same components, same numbers). The price: each call
costs O(rows kept) and the rows are held in memory until `consolidate()`, which makes the current
model the new starting point (later calls are then order-independent among themselves only).
Rows without `times` get the sample count at that starting point, whatever the chunking.
"""
import bisect
import copy
import math
from collections import deque
from typing import Dict, List

import numpy as np

from igmm_layers.errors import InvalidInputError, NotFittedError
from igmm_layers.igmm_data import canonical_order, rank_one_terms, restore_components, validate_samples

__all__ = ["IncrementalGMM"]

_LOG_SKIP = math.log(1e-12)  # posteriors below this fraction of the best are not applied
_LOG_2PI = math.log(2.0 * math.pi)
_min = np.minimum.reduce
_ARRAYS = ("means_", "covariances_", "precisions_", "log_dets_", "support_", "born_", "ids_",
           "first_seen_", "last_seen_", "_log_score")
# the learnt state a batch-mode call starts again from (with _ARRAYS)
_STATE = ("observation_times_", "n_updates_", "n_samples_seen_", "_next_id", "_since_refresh",
          "_prune_queue", "n_features_in_", "sigma_ini_", "_threshold")


class IncrementalGMM:
    """An incremental Gaussian mixture with novelty-driven growth and pruning (sklearn-style).

    Args:
        covariance_scale: delta of the original: sigma_ini = covariance_scale * data_range.
        data_range: extent of the input space per dimension (a number or one per dimension), e.g.
            the size of a map region in metres.
        sigma_ini: initial standard deviation(s) of new components; overrides the two above.
        novelty_constant: tau_nov in (0, 1); x is novel when its squared Mahalanobis distance to
            every component exceeds -2 ln tau_nov.
        v_min, sp_min: pruning: a component older than v_min updates with less than sp_min
            support is removed. Components with support < sp_min are "tentative" (`confirmed_`).
        batch: the model depends only on the multiset of rows given since the last fit/restore/
            consolidate(), not on their order or on how they were split into calls (see above).
        refresh_interval: updates between exact recomputations of precisions and log-determinants.
        max_times: observation times kept per component (the oldest are dropped beyond it).
    """

    def __init__(self, *, covariance_scale: float = 0.01, data_range=1.0, sigma_ini=None,
                 novelty_constant: float = 0.01, v_min: int = 100, sp_min: float = 3.0,
                 batch: bool = False, refresh_interval: int = 1000, max_times: int = 1000):
        self.covariance_scale = covariance_scale
        self.data_range = data_range
        self.sigma_ini = sigma_ini
        self.novelty_constant = novelty_constant
        self.v_min = v_min
        self.sp_min = sp_min
        self.batch = batch
        self.refresh_interval = refresh_interval
        self.max_times = max_times

    # --- parameters -------------------------------------------------------------------------
    def get_params(self, deep: bool = True) -> Dict[str, object]:
        names = ("covariance_scale", "data_range", "sigma_ini", "novelty_constant", "v_min",
                 "sp_min", "batch", "refresh_interval", "max_times")
        return {name: getattr(self, name) for name in names}

    def set_params(self, **params) -> "IncrementalGMM":
        for name, value in params.items():
            if name not in self.get_params():
                raise InvalidInputError(f"unknown parameter {name!r} of IncrementalGMM")
            setattr(self, name, value)
        if not self.batch:
            self.consolidate()
        if self.is_fitted:
            self._check_params()
            self.sigma_ini_ = self._initial_sigma(self.n_features_in_)
            self._rebuild_prune_queue()
        return self

    def _check_params(self) -> None:
        if not 0.0 < self.novelty_constant < 1.0:
            raise InvalidInputError(f"novelty_constant must be in (0, 1), got {self.novelty_constant!r}")
        if not (self.v_min >= 1 and self.sp_min >= 0):
            raise InvalidInputError(f"need v_min >= 1 and sp_min >= 0, got {self.v_min!r}, {self.sp_min!r}")
        if not (self.refresh_interval >= 1 and self.max_times >= 1):
            raise InvalidInputError("refresh_interval and max_times must be at least 1, got "
                                    f"{self.refresh_interval!r}, {self.max_times!r}")
        self._threshold = -2.0 * math.log(self.novelty_constant)

    def _initial_sigma(self, dim: int) -> np.ndarray:
        if self.sigma_ini is not None:
            sigma = np.broadcast_to(np.asarray(self.sigma_ini, float), (dim,)).copy()
        else:
            sigma = self.covariance_scale * np.broadcast_to(np.asarray(self.data_range, float), (dim,))
        if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
            raise InvalidInputError(f"initial standard deviations must be positive, got {sigma.tolist()}"
                                    " (covariance_scale * data_range or sigma_ini)")
        return sigma

    # --- fitting ------------------------------------------------------------------------------
    @property
    def is_fitted(self) -> bool:
        return hasattr(self, "means_")

    def _reset(self, dim: int) -> None:
        self._check_params()
        self.sigma_ini_ = self._initial_sigma(dim)
        self.n_features_in_ = dim
        self.means_ = np.zeros((0, dim))
        self.covariances_ = np.zeros((0, dim, dim))
        self.precisions_ = np.zeros((0, dim, dim))
        for name in ("log_dets_", "support_", "first_seen_", "last_seen_", "_log_score"):
            setattr(self, name, np.zeros(0))
        self.born_ = np.zeros(0, dtype=np.int64)
        self.ids_ = np.zeros(0, dtype=np.int64)
        self.observation_times_: List[List[float]] = []
        self.n_updates_ = 0
        self.n_samples_seen_ = 0
        self._next_id = 0
        self._since_refresh = 0
        self._prune_queue: deque = deque()
        self.consolidate()

    def fit(self, X, sample_weight=None, *, measurement_cov=None, times=None) -> "IncrementalGMM":
        """Forget everything, then learn X (one partial_fit call)."""
        for name in _ARRAYS + ("n_features_in_",):
            self.__dict__.pop(name, None)
        self.consolidate()
        return self.partial_fit(X, sample_weight, measurement_cov=measurement_cov, times=times)

    def partial_fit(self, X, sample_weight=None, *, measurement_cov=None, times=None) -> "IncrementalGMM":
        """Learn the rows of X (n, D) in order (in batch mode: relearn all kept rows, see above).

        Args:
            sample_weight: (n,) positive weights (detection confidences); default 1.
            measurement_cov: (n, D, D) or (n, D) (variances) measurement covariances; default none.
            times: (n,) observation times (s); default the running sample count (in batch mode
                the count at the starting point, for every row).
        """
        dim = self.n_features_in_ if self.is_fitted else None
        t0 = self.n_samples_seen_ if dim else 0
        if self.batch and self._batch_start is not None:
            t0 = self._batch_start["n_samples_seen_"]
        X, weights, covs, times = validate_samples(X, sample_weight, measurement_cov, times, dim,
                                                   t0, self.batch)
        if not self.is_fitted:
            self._reset(X.shape[1])
        if self.batch:
            self._learn_batch(X, weights, covs, times)
            return self
        self.consolidate()
        terms = rank_one_terms(covs) if covs is not None else None
        for i in range(len(X)):
            self._learn_one(X[i], float(weights[i]), terms[i] if terms else (), float(times[i]))
        self.n_samples_seen_ += len(X)
        return self

    # batch mode: the kept rows and the state they are relearnt from
    _batch_start = None
    _batch_rows: List[tuple] = []

    def consolidate(self) -> "IncrementalGMM":
        """Batch mode: make the current model the starting point of later calls and drop the
        kept rows (bounds memory and the cost per call; order independence then holds among the
        later calls only). Harmless in sequential mode."""
        self._batch_start = None
        self._batch_rows = []
        return self

    @property
    def n_batch_rows_(self) -> int:
        """Rows kept for relearning in batch mode (0 in sequential mode)."""
        return sum(len(rows[0]) for rows in self._batch_rows)

    def _learn_batch(self, X, weights, covs, times) -> None:
        dim = X.shape[1]
        if covs is None:  # zero covariance: no rank-one terms, the same update as none
            covs = np.zeros((len(X), dim, dim))
        if self._batch_start is None:
            self._batch_start = copy.deepcopy({name: getattr(self, name) for name in _ARRAYS + _STATE})
        rows = self._batch_rows + [(X, weights, covs, times)]
        for name, value in copy.deepcopy(self._batch_start).items():
            setattr(self, name, value)
        X, weights, covs, times = (np.concatenate(column) for column in zip(*rows))
        terms = rank_one_terms(covs)
        for i in canonical_order(X, weights, times, covs):
            self._learn_one(X[i], float(weights[i]), terms[i], float(times[i]))
        self.n_samples_seen_ += len(X)
        self._batch_rows = rows

    def _learn_one(self, x: np.ndarray, weight: float, terms, time: float) -> None:
        if len(self.support_) == 0:
            self._add(x, weight, terms, time)
            return
        e = x - self.means_
        pe = np.einsum("kij,kj->ki", self.precisions_, e)
        maha = np.einsum("kd,kd->k", e, pe)
        if _min(maha) > self._threshold:
            self._add(x, weight, terms, time)
            return
        score = self._log_score - 0.5 * maha
        best = int(score.argmax())
        active = (score > score[best] + _LOG_SKIP).nonzero()[0]
        self.n_updates_ += 1
        if len(active) == 1:
            self._update_one(best, weight, e[best], pe[best], float(maha[best]), terms)
        else:
            post = np.exp(score[active] - score[best])
            self._update_many(active, weight * post / post.sum(), e[active], pe[active],
                              maha[active], terms)
        self._record(best, time)
        if self._prune_queue and self._prune_queue[0][0] <= self.n_updates_:
            self._prune_due()
        self._since_refresh += 1
        if self._since_refresh >= self.refresh_interval:
            self.refresh()

    def _update_one(self, j: int, gain: float, e, pe, maha: float, terms) -> None:
        support = float(self.support_[j]) + gain
        self.support_[j] = support
        w = gain / support
        self.means_[j] += w * e
        cov = self.covariances_[j]
        cov += w * (e[:, None] * e[None, :])
        cov *= 1.0 - w
        prec = self.precisions_[j]
        prec -= (w / (1.0 + w * maha)) * (pe[:, None] * pe[None, :])
        prec /= 1.0 - w
        log_det = float(self.log_dets_[j]) + math.log1p(w * maha) + len(e) * math.log1p(-w)
        for lam, u in terms:  # + w R, one eigen-direction of R at a time
            a = w * lam
            cov += a * (u[:, None] * u[None, :])
            pu = prec @ u
            q = float(u @ pu)
            prec -= (a / (1.0 + a * q)) * (pu[:, None] * pu[None, :])
            log_det += math.log1p(a * q)
        self.log_dets_[j] = log_det
        self._log_score[j] = math.log(support) - 0.5 * log_det

    def _update_many(self, idx, gain, e, pe, maha, terms) -> None:
        support = self.support_[idx] + gain
        self.support_[idx] = support
        w = gain / support
        w3 = w[:, None, None]
        self.means_[idx] += w[:, None] * e
        cov = (self.covariances_[idx] + w3 * (e[:, :, None] * e[:, None, :])) * (1.0 - w3)
        prec = (self.precisions_[idx] - (w / (1.0 + w * maha))[:, None, None]
                * (pe[:, :, None] * pe[:, None, :])) / (1.0 - w3)
        log_det = self.log_dets_[idx] + np.log1p(w * maha) + e.shape[1] * np.log1p(-w)
        for lam, u in terms:
            a = w * lam
            cov += a[:, None, None] * np.outer(u, u)[None]
            pu = prec @ u
            q = pu @ u
            prec -= (a / (1.0 + a * q))[:, None, None] * (pu[:, :, None] * pu[:, None, :])
            log_det += np.log1p(a * q)
        self.covariances_[idx] = cov
        self.precisions_[idx] = prec
        self.log_dets_[idx] = log_det
        self._log_score[idx] = np.log(support) - 0.5 * log_det

    def _add(self, x: np.ndarray, weight: float, terms, time: float) -> None:
        # sigma_ini^2 I + R, its inverse and log-determinant by rank-one steps (no LAPACK call)
        variances = self.sigma_ini_ ** 2
        cov, prec = np.diag(variances), np.diag(1.0 / variances)
        log_det = float(np.log(variances).sum())
        for lam, u in terms:
            cov += lam * np.outer(u, u)
            pu = prec @ u
            q = float(u @ pu)
            prec -= (lam / (1.0 + lam * q)) * np.outer(pu, pu)
            log_det += math.log1p(lam * q)
        uid = self._next_id
        self._next_id += 1
        new = {"means_": x[None], "covariances_": cov[None], "precisions_": prec[None],
               "log_dets_": [log_det], "support_": [weight], "born_": [self.n_updates_],
               "ids_": [uid], "first_seen_": [time], "last_seen_": [time],
               "_log_score": [math.log(weight) - 0.5 * log_det]}
        for name, value in new.items():
            old = getattr(self, name)
            setattr(self, name, np.concatenate([old, np.asarray(value, dtype=old.dtype)]))
        self.observation_times_.append([time])
        self._prune_queue.append((self.n_updates_ + self.v_min, uid))

    def _record(self, j: int, time: float) -> None:
        times = self.observation_times_[j]
        if not times or time >= times[-1]:
            times.append(time)
        else:
            bisect.insort(times, time)
        if len(times) > self.max_times:
            del times[0]
        self.first_seen_[j] = min(self.first_seen_[j], time)
        self.last_seen_[j] = max(self.last_seen_[j], time)

    def _prune_due(self) -> None:
        # Support only grows, so "v > v_min and sp < sp_min" needs checking once: when v passes v_min.
        while self._prune_queue and self._prune_queue[0][0] <= self.n_updates_:
            _, uid = self._prune_queue.popleft()
            found = np.flatnonzero(self.ids_ == uid)
            if len(found) and self.support_[found[0]] < self.sp_min:
                self.remove_components([int(found[0])])

    def _rebuild_prune_queue(self) -> None:
        due = self.born_ + self.v_min
        order = np.argsort(due, kind="stable")
        self._prune_queue = deque((int(due[i]), int(self.ids_[i])) for i in order
                                  if due[i] > self.n_updates_ or self.support_[i] < self.sp_min)
        if self._prune_queue and self._prune_queue[0][0] <= self.n_updates_:
            self._prune_due()

    def remove_components(self, indices) -> None:
        """Delete components by index (pruning; also usable by callers)."""
        indices = sorted({int(i) for i in indices}, reverse=True)
        keep = np.ones(len(self.support_), dtype=bool)
        keep[indices] = False
        for name in _ARRAYS:
            setattr(self, name, getattr(self, name)[keep])
        for i in indices:
            del self.observation_times_[i]

    def refresh(self) -> None:
        """Recompute precisions and log-determinants exactly from the covariances (O(K D^3))."""
        self._since_refresh = 0
        if len(self.support_) == 0:
            return
        self.covariances_ = 0.5 * (self.covariances_ + np.swapaxes(self.covariances_, 1, 2))
        self.precisions_ = np.linalg.inv(self.covariances_)
        self.log_dets_ = np.linalg.slogdet(self.covariances_)[1]
        self._log_score = np.log(self.support_) - 0.5 * self.log_dets_

    # --- fitted quantities --------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not self.is_fitted or len(self.support_) == 0:
            raise NotFittedError("this IncrementalGMM has no components yet; call partial_fit first")

    @property
    def n_components_(self) -> int:
        return len(self.support_) if self.is_fitted else 0

    @property
    def weights_(self) -> np.ndarray:
        """Mixture weights p(j) = sp_j / sum sp."""
        return self.support_ / self.support_.sum() if self.n_components_ else np.zeros(0)

    @property
    def ages_(self) -> np.ndarray:
        """v_j: how many updates each component has taken part in (1 when created)."""
        return 1 + self.n_updates_ - self.born_

    @property
    def confirmed_(self) -> np.ndarray:
        """Components with at least sp_min support (the others may still be pruned)."""
        return self.support_ >= self.sp_min

    # --- prediction ---------------------------------------------------------------------------
    def _check_X(self, X) -> np.ndarray:
        self._check_fitted()
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n_features_in_ or not np.all(np.isfinite(X)):
            raise InvalidInputError(f"X must be a finite (n, {self.n_features_in_}) array, got shape "
                                    f"{X.shape}")
        return X

    def mahalanobis(self, X) -> np.ndarray:
        """Squared Mahalanobis distances (n, K) of the rows of X to every component."""
        X = self._check_X(X)
        out = np.empty((len(X), self.n_components_))
        for start in range(0, len(X), 512):
            e = X[start:start + 512, None, :] - self.means_[None]
            out[start:start + 512] = np.einsum("nkd,kde,nke->nk", e, self.precisions_, e)
        return out

    def _weighted_log_density(self, X) -> np.ndarray:
        maha = self.mahalanobis(X)
        const = self.n_features_in_ * _LOG_2PI
        return np.log(self.weights_) - 0.5 * (maha + self.log_dets_ + const)

    def score_samples(self, X) -> np.ndarray:
        """log p(x) of each row."""
        log_dens = self._weighted_log_density(X)
        top = log_dens.max(axis=1, keepdims=True)
        return (top + np.log(np.exp(log_dens - top).sum(axis=1, keepdims=True)))[:, 0]

    def score(self, X, y=None) -> float:
        """Mean log-likelihood of the rows of X (higher is better)."""
        return float(self.score_samples(X).mean())

    def predict_proba(self, X) -> np.ndarray:
        log_dens = self._weighted_log_density(X)
        return np.exp(log_dens - self.score_samples(X)[:, None])

    def predict(self, X) -> np.ndarray:
        """Index of the most probable component of each row."""
        return self._weighted_log_density(X).argmax(axis=1)

    def is_novel(self, X) -> np.ndarray:
        """Whether each row would start a new component."""
        return self.mahalanobis(X).min(axis=1) > -2.0 * math.log(self.novelty_constant)

    # --- state as plain data ------------------------------------------------------------------
    def to_dict(self) -> Dict[str, object]:
        """Parameters and fitted state as plain Python data (JSON-serialisable)."""
        state: Dict[str, object] = {"params": dict(self.get_params()), "fitted": self.is_fitted}
        if not self.is_fitted:
            return state
        state.update(n_features_in=self.n_features_in_, n_updates=self.n_updates_,
                     n_samples_seen=self.n_samples_seen_, components=[
                         {"mean": self.means_[j].tolist(), "covariance": self.covariances_[j].tolist(),
                          "support": float(self.support_[j]), "age": int(self.ages_[j]),
                          "first_seen": float(self.first_seen_[j]),
                          "last_seen": float(self.last_seen_[j]),
                          "times": list(self.observation_times_[j])}
                         for j in range(self.n_components_)])
        return state

    @classmethod
    def from_dict(cls, state: Dict[str, object]) -> "IncrementalGMM":
        """The model that `to_dict` described (precisions recomputed from the covariances)."""
        try:
            model = cls(**dict(state["params"]))
        except (KeyError, TypeError) as err:
            raise InvalidInputError(f"not an IncrementalGMM state: {err}") from err
        if state.get("fitted"):
            restore_components(model, state)
        return model

    def __repr__(self) -> str:
        return f"IncrementalGMM(n_components={self.n_components_}, sigma_ini={self.sigma_ini!r})"
