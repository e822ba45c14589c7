"""Noisy object detections with known ground truth (pure NumPy; no ROS).

A scene is a list of objects (class, position of any dimension, size). `simulate_detections`
draws for each object a Poisson number of detections around its position with Gaussian noise,
adds uniform clutter (false detections of the scene's classes) so that it makes up a given
fraction of all detections, shuffles everything into a random order and stamps it with
increasing times. `Detections.truth` says which object each detection came from (-1: clutter),
so learners can be scored against the truth they did not produce.

    scene = random_scene(10, bounds=[(0, 20), (0, 20)], random_state=1)
    dets = simulate_detections(scene, mean_detections=20, noise_std=0.1, clutter_fraction=0.1,
                               random_state=2)
    building_scene(generate_building(0))   # the generated building's objects as a scene

`building_detections(config)` and `place_sightings(building, config)` are what the
object_detection_sim node publishes for its `ObjectDetectionSimParams`, so that anyone holding the same
parameters (the demo, tests) knows the truth behind its messages.
"""
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from robot_sim.building import Building, generate_building
from robot_sim.errors import SimError
from robot_sim.params import ObjectDetectionSimParams

__all__ = ["SceneObject", "Detections", "random_scene", "building_scene", "simulate_detections",
           "scene_bounds", "building_detections", "place_sightings"]

Bounds = Sequence[Tuple[float, float]]


@dataclass(frozen=True)
class SceneObject:
    """A true object: `position` and `size` (extent per axis, m) have the scene's dimension."""

    class_name: str
    position: Tuple[float, ...]
    size: Tuple[float, ...] = ()


@dataclass
class Detections:
    """n detections in time order; `truth[i]` is the index of the scene object or -1 (clutter)."""

    class_names: List[str]
    positions: np.ndarray
    confidences: np.ndarray
    sizes: np.ndarray
    stamps: np.ndarray
    truth: np.ndarray

    def __len__(self) -> int:
        return len(self.class_names)

    def subset(self, index) -> "Detections":
        """The detections at `index` (a boolean mask or integer indices), in that order."""
        index = np.arange(len(self))[np.asarray(index)]
        return Detections([self.class_names[i] for i in index], self.positions[index],
                          self.confidences[index], self.sizes[index], self.stamps[index],
                          self.truth[index])

    def of_class(self, class_name: str) -> "Detections":
        return self.subset(np.array([name == class_name for name in self.class_names], dtype=bool))

    @property
    def clutter_fraction(self) -> float:
        return float(np.mean(self.truth < 0)) if len(self) else 0.0


def _rng(random_state) -> np.random.Generator:
    return random_state if isinstance(random_state, np.random.Generator) else \
        np.random.default_rng(random_state)


def _check_bounds(bounds: Bounds) -> np.ndarray:
    box = np.asarray(bounds, dtype=float)
    if box.ndim != 2 or box.shape[1] != 2 or len(box) == 0 or np.any(box[:, 1] <= box[:, 0]):
        raise SimError(f"bounds must be [(low, high), ...] with low < high, got {bounds!r}")
    return box


def random_scene(n_objects: int, *, bounds: Bounds = ((0.0, 20.0), (0.0, 20.0)),
                 min_separation: float = 1.5, classes: Sequence[str] = ("object",),
                 size: Optional[Sequence[float]] = None, random_state=None,
                 max_tries: int = 10000) -> List[SceneObject]:
    """`n_objects` objects placed uniformly in `bounds`, at least `min_separation` apart.

    Classes are assigned round-robin from `classes`; `size` (per axis) is given to every object.
    """
    if n_objects < 0:
        raise SimError(f"n_objects must be >= 0, got {n_objects}")
    box = _check_bounds(bounds)
    rng = _rng(random_state)
    placed: List[np.ndarray] = []
    for _ in range(max_tries):
        if len(placed) == n_objects:
            break
        candidate = rng.uniform(box[:, 0], box[:, 1])
        if all(np.linalg.norm(candidate - p) >= min_separation for p in placed):
            placed.append(candidate)
    if len(placed) < n_objects:
        raise SimError(f"could not place {n_objects} objects {min_separation} m apart in {bounds!r}")
    extent = tuple(float(s) for s in size) if size is not None else ()
    return [SceneObject(classes[i % len(classes)], tuple(float(v) for v in p), extent)
            for i, p in enumerate(placed)]


def building_scene(building) -> List[SceneObject]:
    """The objects of a `robot_sim.building.Building` (2-D positions, x/y extents)."""
    return [SceneObject(obj.class_name, (obj.x, obj.y), tuple(obj.size[:2])) for obj in building.objects]


def scene_bounds(scene: Sequence[SceneObject], margin: float = 1.0) -> np.ndarray:
    """The bounding box of the objects' positions, `margin` larger on every side."""
    positions = np.array([obj.position for obj in scene], dtype=float)
    return np.stack([positions.min(axis=0) - margin, positions.max(axis=0) + margin], axis=1)


def simulate_detections(scene: Sequence[SceneObject], *, mean_detections: float = 20.0,
                        noise_std: float = 0.1, clutter_fraction: float = 0.1,
                        bounds: Optional[Bounds] = None, confidence: Tuple[float, float] = (1.0, 1.0),
                        clutter_confidence: Optional[Tuple[float, float]] = None,
                        extent_spread: bool = False, start_time: float = 0.0,
                        duration: float = 60.0, random_state=None) -> Detections:
    """Detections of `scene` in a random order (see the module docstring).

    Args:
        mean_detections: Poisson mean of the number of detections of each object.
        noise_std: standard deviation (m) of the Gaussian position noise on every axis.
        clutter_fraction: share of clutter among all detections, in [0, 1).
        bounds: where clutter falls (uniform); default the scene's bounding box plus 1 m.
        confidence, clutter_confidence: uniform ranges of the reported confidences.
        extent_spread: detections fall anywhere on the object's extent (plus noise), not only
            around its centre, as a detector that sees different parts of a large object.
        start_time, duration: stamps are sorted uniform times in this interval.
    """
    if not scene:
        raise SimError("the scene has no objects")
    if not 0.0 <= clutter_fraction < 1.0 or mean_detections < 0 or noise_std < 0:
        raise SimError("need 0 <= clutter_fraction < 1, mean_detections >= 0 and noise_std >= 0; got "
                       f"{clutter_fraction}, {mean_detections}, {noise_std}")
    rng = _rng(random_state)
    centres = np.array([obj.position for obj in scene], dtype=float)
    dim = centres.shape[1]
    counts = rng.poisson(mean_detections, size=len(scene))
    truth = np.repeat(np.arange(len(scene)), counts)
    positions = centres[truth] + rng.normal(0.0, noise_std, size=(len(truth), dim))
    sizes = np.array([_size(obj, dim) for obj in scene])[truth] if len(truth) else np.zeros((0, dim))
    if extent_spread and len(truth):
        positions += rng.uniform(-0.5, 0.5, size=positions.shape) * sizes
    n_clutter = int(round(clutter_fraction / (1.0 - clutter_fraction) * len(truth)))
    box = _check_bounds(bounds) if bounds is not None else scene_bounds(scene)
    if len(box) != dim:
        raise SimError(f"bounds have {len(box)} dimensions, the scene has {dim}")
    clutter_pos = rng.uniform(box[:, 0], box[:, 1], size=(n_clutter, dim))
    class_pool = sorted({obj.class_name for obj in scene})
    clutter_classes = [class_pool[i] for i in rng.integers(0, len(class_pool), size=n_clutter)]
    low, high = confidence
    clutter_low, clutter_high = clutter_confidence or confidence
    names = [scene[i].class_name for i in truth] + clutter_classes
    all_conf = np.concatenate([rng.uniform(low, high, len(truth)),
                               rng.uniform(clutter_low, clutter_high, n_clutter)])
    all_pos = np.concatenate([positions, clutter_pos])
    all_sizes = np.concatenate([sizes, np.zeros((n_clutter, dim))])
    all_truth = np.concatenate([truth, np.full(n_clutter, -1)])
    order = rng.permutation(len(names))
    stamps = start_time + np.sort(rng.uniform(0.0, duration, len(names)))
    return Detections([names[i] for i in order], all_pos[order], all_conf[order], all_sizes[order],
                      stamps, all_truth[order])


def _size(obj: SceneObject, dim: int) -> np.ndarray:
    size = np.zeros(dim)
    size[:min(dim, len(obj.size))] = obj.size[:dim]
    return size


def building_detections(config: ObjectDetectionSimParams) -> Tuple[Building, Detections]:
    """The generated building of `config.seed` and object_detection_sim's detections of it."""
    building = generate_building(config.seed)
    detections = simulate_detections(building_scene(building), mean_detections=config.mean_detections,
                                     noise_std=config.noise_std, clutter_fraction=config.clutter_fraction,
                                     extent_spread=config.extent_spread, confidence=(0.6, 1.0),
                                     random_state=config.random_seed)
    return building, detections


def place_sightings(building: Building, config: ObjectDetectionSimParams) -> List[Tuple[str, np.ndarray]]:
    """(label, noisy x/y) sightings of every labelled place, `config.place_detections` each."""
    rng = np.random.default_rng(config.random_seed + 1)
    return [(name, np.array(xy) + rng.normal(0, config.noise_std, 2))
            for name, xy in sorted(building.labels.items()) for _ in range(config.place_detections)]
