"""A slow, literal IGMM for checking the fast one (tests) and for the O(D^3) comparison (bench).

Every step recomputes inverses and determinants from the covariance matrices, updates every
component with its full posterior and counts ages explicitly, as the algorithm is written in
Engel and Heinen (2010). `covariance_update="published"` uses the update as usually printed,
C <- (1 - w) C + w e* e*^T - dmu dmu^T (e* = x - new mean, dmu = new mean - old mean), which can
make a covariance indefinite; "exact" (default) uses C <- (1 - w)(C + w e e^T).
"""
import math
from typing import List, Optional

import numpy as np

from igmm_layers.errors import InvalidInputError

__all__ = ["ReferenceIGMM"]


class ReferenceIGMM:
    """Plain loops over components; O(K D^3) per update."""

    def __init__(self, *, sigma_ini, novelty_constant: float = 0.01, v_min: int = 100,
                 sp_min: float = 3.0, covariance_update: str = "exact"):
        if covariance_update not in ("exact", "published"):
            raise InvalidInputError(f"covariance_update must be 'exact' or 'published', "
                                    f"got {covariance_update!r}")
        self.sigma_ini = sigma_ini
        self.novelty_constant = novelty_constant
        self.v_min = v_min
        self.sp_min = sp_min
        self.covariance_update = covariance_update
        self.means: List[np.ndarray] = []
        self.covs: List[np.ndarray] = []
        self.support: List[float] = []
        self.ages: List[int] = []

    def partial_fit(self, X, sample_weight=None, measurement_cov=None) -> "ReferenceIGMM":
        X = np.asarray(X, dtype=float)
        weights = np.ones(len(X)) if sample_weight is None else np.asarray(sample_weight, float)
        for i, x in enumerate(X):
            cov = None if measurement_cov is None else np.asarray(measurement_cov[i], float)
            self.learn_one(x, float(weights[i]), cov)
        return self

    def learn_one(self, x: np.ndarray, weight: float = 1.0, meas_cov: Optional[np.ndarray] = None):
        dim = len(x)
        meas_cov = np.zeros((dim, dim)) if meas_cov is None else meas_cov
        threshold = -2.0 * math.log(self.novelty_constant)
        mahas = [float((x - m) @ np.linalg.inv(c) @ (x - m)) for m, c in zip(self.means, self.covs)]
        if not mahas or min(mahas) > threshold:
            sigma = np.broadcast_to(np.asarray(self.sigma_ini, float), (dim,))
            self.means.append(x.copy())
            self.covs.append(np.diag(sigma ** 2) + meas_cov)
            self.support.append(weight)
            self.ages.append(1)
            return
        total = sum(self.support)
        log_joint = [math.log(sp / total) - 0.5 * (dim * math.log(2 * math.pi)
                                                   + np.linalg.slogdet(c)[1] + maha)
                     for sp, c, maha in zip(self.support, self.covs, mahas)]
        top = max(log_joint)
        norm = top + math.log(sum(math.exp(v - top) for v in log_joint))
        for j in range(len(self.means)):
            post = math.exp(log_joint[j] - norm)
            self.ages[j] += 1
            self.support[j] += weight * post
            w = weight * post / self.support[j]
            e = x - self.means[j]
            new_mean = self.means[j] + w * e
            if self.covariance_update == "exact":
                self.covs[j] = (1 - w) * (self.covs[j] + w * np.outer(e, e)) + w * meas_cov
            else:
                e_new, dmu = x - new_mean, new_mean - self.means[j]
                self.covs[j] = (1 - w) * self.covs[j] + w * np.outer(e_new, e_new) - np.outer(dmu, dmu)
            self.means[j] = new_mean
        keep = [j for j in range(len(self.means))
                if not (self.ages[j] > self.v_min and self.support[j] < self.sp_min)]
        for name in ("means", "covs", "support", "ages"):
            values = getattr(self, name)
            setattr(self, name, [values[j] for j in keep])
