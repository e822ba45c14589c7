"""Object layers: per map region and layer kind, one IncrementalGMM per object class.

`LayerSet` is the layer server's whole knowledge: a dictionary (region id, kind) -> `Layer`,
where kind is "objects" or "regions" (labelled places). Layers appear when the first
observation for them arrives, with the parameters configured for their region (or the
defaults). `ClusterTable` holds the clusters of several classes as arrays, for the queries.
"""
from dataclasses import asdict, dataclass, field, fields
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from igmm_layers.errors import InvalidInputError, UnknownNameError
from igmm_layers.hierarchy import ClassHierarchy
from igmm_layers.igmm import IncrementalGMM

__all__ = ["LAYER_KINDS", "LayerParams", "Layer", "LayerSet", "ClusterTable", "check_kind"]

LAYER_KINDS = ("objects", "regions")


def check_kind(kind: str) -> str:
    """The layer kind of a request ("" means "objects")."""
    kind = kind or "objects"
    if kind not in LAYER_KINDS:
        raise UnknownNameError(f"unknown layer {kind!r}; layers are {', '.join(LAYER_KINDS)}")
    return kind


@dataclass
class LayerParams:
    """Parameters of one layer (the original's per-layer parameters plus a few new ones).

    sigma_ini of new components = covariance_scale * region_size (m).
    """

    covariance_scale: float = 0.01
    region_size: float = 20.0
    novelty_constant: float = 0.01
    v_min: int = 100
    sp_min: float = 3.0
    dimensions: int = 2
    batch: bool = False
    max_times: int = 1000
    observation_topic: str = ""

    @classmethod
    def from_dict(cls, values: Mapping[str, object], base: Optional["LayerParams"] = None) -> "LayerParams":
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise InvalidInputError(f"unknown layer parameter(s) {unknown}; known: {sorted(known)}")
        merged = asdict(base or cls())
        merged.update(values)
        try:
            params = cls(covariance_scale=float(merged["covariance_scale"]),
                         region_size=float(merged["region_size"]),
                         novelty_constant=float(merged["novelty_constant"]),
                         v_min=int(merged["v_min"]), sp_min=float(merged["sp_min"]),
                         dimensions=int(merged["dimensions"]), batch=bool(merged["batch"]),
                         max_times=int(merged["max_times"]),
                         observation_topic=str(merged["observation_topic"]))
        except (TypeError, ValueError) as err:
            raise InvalidInputError(f"bad layer parameter value: {err}") from err
        params.check()
        return params

    def check(self) -> None:
        if self.dimensions not in (2, 3):
            raise InvalidInputError(f"dimensions must be 2 or 3, got {self.dimensions}")
        if not (self.covariance_scale > 0 and self.region_size > 0):
            raise InvalidInputError(f"covariance_scale and region_size must be positive, got "
                                    f"{self.covariance_scale}, {self.region_size}")
        self.estimator()._check_params()

    def estimator(self) -> IncrementalGMM:
        return IncrementalGMM(covariance_scale=self.covariance_scale, data_range=self.region_size,
                              novelty_constant=self.novelty_constant, v_min=self.v_min,
                              sp_min=self.sp_min, batch=self.batch, max_times=self.max_times)


@dataclass
class ClusterTable:
    """Clusters as parallel arrays; positions in the layer's dimension (2 or 3)."""

    class_names: List[str] = field(default_factory=list)
    region_ids: List[str] = field(default_factory=list)
    kinds: List[str] = field(default_factory=list)
    means: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    covariances: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    support: np.ndarray = field(default_factory=lambda: np.zeros(0))
    observations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    first_seen: np.ndarray = field(default_factory=lambda: np.zeros(0))
    last_seen: np.ndarray = field(default_factory=lambda: np.zeros(0))
    times: List[List[float]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.class_names)

    @classmethod
    def concat(cls, tables: Sequence["ClusterTable"]) -> "ClusterTable":
        tables = [t for t in tables if len(t)]
        if not tables:
            return cls()
        means = np.concatenate([t.means for t in tables])
        covs = np.concatenate([t.covariances for t in tables])
        joined = {name: sum((getattr(t, name) for t in tables), [])
                  for name in ("class_names", "region_ids", "kinds", "times")}
        arrays = {name: np.concatenate([getattr(t, name) for t in tables])
                  for name in ("weights", "support", "observations", "first_seen", "last_seen")}
        return cls(means=means, covariances=covs, **joined, **arrays)

    def take(self, index) -> "ClusterTable":
        index = np.arange(len(self))[np.asarray(index)]
        return ClusterTable([self.class_names[i] for i in index], [self.region_ids[i] for i in index],
                            [self.kinds[i] for i in index], self.means[index], self.covariances[index],
                            self.weights[index], self.support[index], self.observations[index],
                            self.first_seen[index], self.last_seen[index],
                            [self.times[i] for i in index])


class Layer:
    """One region's layer of one kind: an IncrementalGMM per class."""

    def __init__(self, region_id: str, kind: str, params: LayerParams):
        self.region_id = region_id
        self.kind = check_kind(kind)
        self.params = params
        self.models: Dict[str, IncrementalGMM] = {}

    @property
    def classes(self) -> List[str]:
        return sorted(name for name, model in self.models.items() if model.n_components_)

    def observe(self, class_name: str, positions, confidences=None, measurement_cov=None,
                times=None) -> None:
        """Learn detections of one class: positions (n, >= dimensions) in the map frame."""
        if not class_name:
            raise InvalidInputError("observation without a class name")
        dim = self.params.dimensions
        positions = np.asarray(positions, dtype=float)
        if positions.ndim != 2 or positions.shape[1] < dim:
            raise InvalidInputError(f"positions must be (n, >= {dim}), got shape {positions.shape}")
        if confidences is not None:
            conf = np.asarray(confidences, dtype=float)
            if np.any(~(conf > 0) | (conf > 1)):
                bad = conf[~(conf > 0) | (conf > 1)][:5]
                raise InvalidInputError(f"confidences must be in (0, 1], got {bad}")
        if measurement_cov is not None:
            measurement_cov = np.asarray(measurement_cov, dtype=float)[:, :dim, :dim]
        model = self.models.get(class_name)
        if model is None:
            model = self.params.estimator()
        model.partial_fit(positions[:, :dim], confidences, measurement_cov=measurement_cov, times=times)
        self.models[class_name] = model

    def table(self, classes: Iterable[str], *, confirmed_only: bool = True) -> ClusterTable:
        """The clusters of these classes; its arrays are copies, its `times` lists the model's own
        (read them only while the layer cannot change)."""
        tables = []
        for name in classes:
            model = self.models.get(name)
            if model is None or not model.n_components_:
                continue
            keep = model.confirmed_ if confirmed_only else np.ones(model.n_components_, dtype=bool)
            idx = np.flatnonzero(keep)
            n = len(idx)
            tables.append(ClusterTable(
                [name] * n, [self.region_id] * n, [self.kind] * n, model.means_[idx],
                model.covariances_[idx], model.weights_[idx], model.support_[idx],
                model.ages_[idx], model.first_seen_[idx], model.last_seen_[idx],
                [model.observation_times_[i] for i in idx]))  # shared, read-only: no copies
        return ClusterTable.concat(tables)

    def n_clusters(self, confirmed_only: bool = True) -> int:
        return int(sum((m.confirmed_.sum() if confirmed_only else m.n_components_)
                       for m in self.models.values() if m.n_components_))

    def to_dict(self) -> Dict[str, object]:
        return {"region_id": self.region_id, "kind": self.kind, "params": asdict(self.params),
                "models": {name: model.to_dict() for name, model in self.models.items()}}

    def restore_class(self, class_name: str, state: Mapping[str, object]) -> None:
        """Replace one class model by a saved `IncrementalGMM.to_dict` state (params: this layer's)."""
        model = IncrementalGMM.from_dict({**state, "params": self.params.estimator().get_params()})
        if model.is_fitted and model.n_features_in_ != self.params.dimensions:
            raise InvalidInputError(f"saved clusters of {class_name!r} have {model.n_features_in_} "
                                    f"dimensions, layer {self.region_id}/{self.kind} has "
                                    f"{self.params.dimensions}")
        self.models[class_name] = model


class LayerSet:
    """All layers: (region id, kind) -> Layer, plus per-region parameters and the class hierarchy."""

    def __init__(self, *, defaults: Optional[LayerParams] = None,
                 region_params: Optional[Mapping[Tuple[str, str], LayerParams]] = None,
                 hierarchy: Optional[ClassHierarchy] = None, default_region: str = "default"):
        self.defaults = defaults or LayerParams()
        self.region_params: Dict[Tuple[str, str], LayerParams] = dict(region_params or {})
        self.hierarchy = hierarchy or ClassHierarchy()
        self.default_region = default_region
        self.layers: Dict[Tuple[str, str], Layer] = {}
        dims = {p.dimensions for p in self.region_params.values()} | {self.defaults.dimensions}
        if len(dims) > 1:
            raise InvalidInputError(f"all layers must have the same dimensions, got {sorted(dims)}")
        for region_id, kind in self.region_params:
            self.layer(region_id, kind, create=True)

    def params_for(self, region_id: str, kind: str) -> LayerParams:
        return self.region_params.get((region_id, check_kind(kind)), self.defaults)

    def layer(self, region_id: str, kind: str, *, create: bool = False) -> Layer:
        kind = check_kind(kind)
        region_id = region_id or self.default_region
        key = (region_id, kind)
        if key not in self.layers:
            if not create:
                regions = sorted({r for r, k in self.layers if k == kind})
                raise UnknownNameError(f"unknown region {region_id!r} for layer {kind!r}; regions: "
                                       f"{', '.join(regions) or 'none'}")
            self.layers[key] = Layer(region_id, kind, self.params_for(region_id, kind))
        return self.layers[key]

    def select(self, region_id: str, kind: str) -> List[Layer]:
        """The layers a request means: one region, or every region when region_id is ""."""
        kind = check_kind(kind)
        if region_id:
            return [self.layer(region_id, kind)]
        return [layer for (_, k), layer in sorted(self.layers.items()) if k == kind]

    def resolve(self, name: str, layers: Sequence[Layer]) -> List[str]:
        known = set().union(*(layer.classes for layer in layers)) if layers else set()
        return self.hierarchy.resolve(name, known)

    def table(self, name: str, region_id: str = "", kind: str = "objects") -> ClusterTable:
        """Confirmed clusters of a class, group or "any" in one region or all."""
        layers = self.select(region_id, kind)
        classes = self.resolve(name, layers)
        return ClusterTable.concat([layer.table(classes) for layer in layers])

    def to_dict(self) -> Dict[str, object]:
        return {"hierarchy": self.hierarchy.to_dict(),
                "layers": [layer.to_dict() for _, layer in sorted(self.layers.items())]}
