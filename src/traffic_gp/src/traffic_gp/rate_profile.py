"""A per-place profile of the people rate over the week: the GP's offset (mean function).

One smooth kernel over (x, y) has to learn every place's own shape of the day from few inducing
points; a place's own mean per time bin (the "per-place weekly profile" of the baselines) gets
that shape from the counts directly. `RateProfile` keeps, per place (a rounded (x, y)) and time
bin, the summed counts and exposures; its log rate is the offset the GP adds to its latent
(`TrafficGP(offset=...)`), so the GP models the multiplicative residual log(rate / profile)
(what no per-place mean can know: smooth corrections shared between neighbouring places and
times). Bins (`kind`): "daily" (time of day), "daytype" (Monday-Friday, Saturday, Sunday x time
of day) or "weekly" (time of week), `bin_minutes` wide; times are hours of the week (Monday
00:00 = 0).

Sparse bins are shrunk toward a prior: the place's overall rate x the bin's relative rate over
all places, with `prior_exposure` (in the rows' exposure units) of pseudo-exposure. A place never
seen gets the bin's rate over all places; every rate is floored at a millionth of the mean rate
(half a count over all the exposure if nobody was ever counted), so every log is finite.
`update` adds rows (online: the profile learns with the model); `to_arrays` / `from_arrays`
save and restore it exactly. NumPy only.
"""
from typing import Dict, Optional

import numpy as np

from robot_common.errors import ConfigError
from traffic_gp.errors import ModelFormatError

KINDS = ("daily", "daytype", "weekly")
PLACE_RESOLUTION = 0.01     # metres: rows whose (x, y) round to the same 1 cm are one place
HOURS_PER_WEEK = 168.0
FLOOR_SHARE = 1e-6          # of the mean rate: the lowest rate the profile gives


class RateProfile:
    """Per place and time bin: counts / exposure, shrunk toward place rate x bin shape."""

    def __init__(self, kind: str = "weekly", bin_minutes: float = 60.0,
                 prior_exposure: float = 1.0):
        if kind not in KINDS:
            raise ConfigError(f"unknown profile kind {kind!r}; known: {', '.join(KINDS)}")
        if not (bin_minutes > 0 and 24 * 60 % bin_minutes == 0):
            raise ConfigError(f"bin_minutes={bin_minutes!r} must divide a day")
        if not prior_exposure > 0:
            raise ConfigError(f"prior_exposure={prior_exposure!r} must be positive")
        self.kind, self.bin_minutes, self.prior_exposure = kind, float(bin_minutes), prior_exposure
        self.places_ = np.zeros((0, 2), np.int64)
        self.counts_ = np.zeros((0, self.n_bins))
        self.exposures_ = np.zeros((0, self.n_bins))

    @property
    def n_bins(self) -> int:
        per_day = int(round(24 * 60 / self.bin_minutes))
        return per_day * {"daily": 1, "daytype": 3, "weekly": 7}[self.kind]

    def bins(self, t) -> np.ndarray:
        """Bin index of times t (hours of the week)."""
        t = np.mod(np.asarray(t, float), HOURS_PER_WEEK)
        per_day = int(round(24 * 60 / self.bin_minutes))
        in_day = np.minimum((np.mod(t, 24.0) * 60.0 // self.bin_minutes).astype(np.int64),
                            per_day - 1)
        day = np.minimum((t // 24.0).astype(np.int64), 6)
        if self.kind == "daily":
            return in_day
        if self.kind == "daytype":            # Monday-Friday 0, Saturday 1, Sunday 2
            return np.maximum(day - 4, 0) * per_day + in_day
        return day * per_day + in_day

    @staticmethod
    def _keys(x, y) -> np.ndarray:
        return np.column_stack([np.round(np.asarray(x, float) / PLACE_RESOLUTION),
                                np.round(np.asarray(y, float) / PLACE_RESOLUTION)]).astype(np.int64)

    def _place_index(self, keys: np.ndarray) -> np.ndarray:
        """Index of each key in `places_`, -1 where the place is unknown."""
        out = np.full(len(keys), -1, np.int64)
        if len(self.places_) == 0 or len(keys) == 0:
            return out
        known = {tuple(k): i for i, k in enumerate(self.places_.tolist())}
        unique, inverse = np.unique(keys, axis=0, return_inverse=True)
        lookup = np.array([known.get(tuple(k), -1) for k in unique.tolist()], np.int64)
        return lookup[np.ravel(inverse)]

    def update(self, x, y, t, exposure, count) -> "RateProfile":
        """Add rows (places, times in hours of the week, exposures, counts)."""
        x, y, t, exposure, count = (np.ravel(np.asarray(v, float)) for v in
                                    np.broadcast_arrays(x, y, t, exposure, count))
        if len(x) == 0:
            return self
        keys = self._keys(x, y)
        index = self._place_index(keys)
        new = np.unique(keys[index < 0], axis=0)
        if len(new):
            self.places_ = np.concatenate([self.places_, new])
            pad = np.zeros((len(new), self.n_bins))
            self.counts_ = np.concatenate([self.counts_, pad])
            self.exposures_ = np.concatenate([self.exposures_, pad])
            index = self._place_index(keys)
        bins = self.bins(t)
        np.add.at(self.counts_, (index, bins), count)
        np.add.at(self.exposures_, (index, bins), exposure)
        return self

    def log_rate(self, x, y, t) -> np.ndarray:
        """Log of the profile's rate at places (x, y) and times t (hours of the week)."""
        x, y, t = (np.ravel(v) for v in np.broadcast_arrays(*(np.asarray(v, float)
                                                              for v in (x, y, t))))
        if len(self.places_) == 0:
            raise ModelFormatError("the rate profile holds no rows")
        table, fallback = self._tables()
        index, bins = self._place_index(self._keys(x, y)), self.bins(t)
        return np.where(index >= 0, table[np.maximum(index, 0), bins], fallback[bins])

    def _tables(self):
        """(log rate per place and bin, log rate per bin over all places)."""
        total_count, total_expo = self.counts_.sum(), max(self.exposures_.sum(), 1e-12)
        global_rate = max(total_count, 0.5) / total_expo
        floor = FLOOR_SHARE * global_rate
        bin_expo = self.exposures_.sum(0)
        bin_rate = (self.counts_.sum(0) + self.prior_exposure * global_rate) \
            / (bin_expo + self.prior_exposure)
        place_rate = (self.counts_.sum(1) + self.prior_exposure * global_rate) \
            / (self.exposures_.sum(1) + self.prior_exposure)
        prior = place_rate[:, None] * bin_rate[None, :] / global_rate
        rate = (self.counts_ + self.prior_exposure * prior) / (self.exposures_ + self.prior_exposure)
        return np.log(np.maximum(rate, floor)), np.log(np.maximum(bin_rate, floor))

    # ---- persistence ----------------------------------------------------------------------
    def to_arrays(self) -> Dict[str, np.ndarray]:
        return {"kind": np.array(self.kind), "bin_minutes": np.array(self.bin_minutes),
                "prior_exposure": np.array(self.prior_exposure), "places": self.places_,
                "counts": self.counts_, "exposures": self.exposures_}

    @classmethod
    def from_arrays(cls, arrays: Dict[str, np.ndarray]) -> Optional["RateProfile"]:
        """The profile saved by `to_arrays`, or None for empty `arrays` (a model without one)."""
        if not arrays:
            return None
        try:
            profile = cls(str(arrays["kind"]), float(arrays["bin_minutes"]),
                          float(arrays["prior_exposure"]))
            places = np.asarray(arrays["places"], np.int64).reshape(-1, 2)
            counts = np.asarray(arrays["counts"], float)
            exposures = np.asarray(arrays["exposures"], float)
        except (KeyError, ValueError, TypeError, ConfigError) as err:
            raise ModelFormatError(f"bad saved rate profile: {err}") from err
        if counts.shape != (len(places), profile.n_bins) or exposures.shape != counts.shape:
            raise ModelFormatError(f"saved rate profile of shape {counts.shape} for "
                                   f"{len(places)} places x {profile.n_bins} bins")
        profile.places_, profile.counts_, profile.exposures_ = places, counts, exposures
        return profile
