"""Labelled places and the answers about them.

- `Region`: a labelled place in the map frame, with an optional description (what a visitor's
  sign would say: "the GRASP robotics laboratory").
- `load_label_file(path)` / `parse_labels(data)`: regions from a map_labelling JSON file
  (`{"label": {"x": .., "y": .., "orientation": [qx, qy, qz, qw], "description": ..}}`).
- `load_descriptions(path)` / `with_descriptions(regions, descriptions)`: descriptions from a
  sidecar file (`{label: description}`, YAML or JSON) for label files one cannot edit.
- `descriptions_of`, `distinct_places`: one entry per place name (a label file's place and the
  regions layer's region of the same name are one place).
- `RankedRegion`, `Recommendation`: a ranking's answer.
"""
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

from region_search.errors import LabelFileError
from region_search.text_similarity import tokenize

__all__ = ["Region", "load_label_file", "parse_labels", "load_descriptions", "with_descriptions",
           "descriptions_of", "distinct_places", "RankedRegion", "Recommendation"]


@dataclass(frozen=True)
class Region:
    """A labelled place in the map frame."""

    name: str
    x: float
    y: float
    z: float = 0.0
    orientation: Tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    source: str = "label_file"
    description: str = ""  # optional: what a visitor's sign would say about the place


def parse_labels(data, *, origin: str = "labels") -> List[Region]:
    """Regions from a decoded map_labelling JSON object; LabelFileError names a bad entry."""
    if not isinstance(data, dict):
        raise LabelFileError(f"{origin}: expected a JSON object of labels, got {type(data).__name__}")
    regions = []
    for name, pose in sorted(data.items()):
        if not isinstance(pose, dict) or not all(
                isinstance(pose.get(k), (int, float)) and not isinstance(pose.get(k), bool)
                for k in ("x", "y")):
            raise LabelFileError(f"{origin}: label {name!r} needs numeric 'x' and 'y', got {pose!r}")
        orientation = pose.get("orientation", [0.0, 0.0, 0.0, 1.0])
        if not (isinstance(orientation, (list, tuple)) and len(orientation) == 4
                and all(isinstance(v, (int, float)) for v in orientation)):
            raise LabelFileError(f"{origin}: label {name!r} has a bad orientation {orientation!r} "
                                 "(want [qx, qy, qz, qw])")
        if not tokenize(name):
            raise LabelFileError(f"{origin}: label {name!r} has no letters or digits")
        description = pose.get("description", "")
        if not isinstance(description, str):
            raise LabelFileError(f"{origin}: label {name!r} has a description that is not a "
                                 f"string: {description!r}")
        regions.append(Region(name, float(pose["x"]), float(pose["y"]), float(pose.get("z", 0.0)),
                              tuple(float(v) for v in orientation),
                              description=" ".join(description.split())))
    return regions


def load_label_file(path) -> List[Region]:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as err:
        raise LabelFileError(f"cannot read label file {path}: {err.strerror}") from err
    except ValueError as err:
        raise LabelFileError(f"label file {path} is not valid JSON: {err}") from err
    return parse_labels(data, origin=str(path))


def load_descriptions(path) -> Dict[str, str]:
    """{label: description} from a sidecar file: a YAML (or JSON) mapping of label names to
    strings, e.g. `grasp: the GRASP robotics laboratory`; LabelFileError names a bad entry."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise LabelFileError(f"cannot read description file {path}: {err.strerror}") from err
    except yaml.YAMLError as err:
        raise LabelFileError(f"description file {path} is not valid YAML/JSON: {err}") from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise LabelFileError(f"{path}: expected a mapping of label -> description, got "
                             f"{type(data).__name__}")
    for name, text in data.items():
        if not isinstance(name, str) or not isinstance(text, str):
            raise LabelFileError(f"{path}: entry {name!r}: {text!r} is not label: description text")
    return {name: " ".join(text.split()) for name, text in data.items()}


def with_descriptions(regions: Sequence[Region], descriptions: Dict[str, str]) -> List[Region]:
    """The regions with the descriptions given for their names (these replace a label file's)."""
    from dataclasses import replace

    return [replace(r, description=descriptions[r.name]) if r.name in descriptions else r
            for r in regions]


def descriptions_of(regions: Sequence[Region]) -> Dict[str, str]:
    """{label: its description} (several regions of one name: the first non-empty one)."""
    described: Dict[str, str] = {}
    for region in regions:
        if not described.get(region.name):
            described[region.name] = region.description
    return described


def distinct_places(regions: Sequence[Region]) -> List[Region]:
    """One region per place name, in first-seen order: a label file's entry gives the pose
    (else the first region of that name), the first non-empty description is kept and the
    sources are joined ("label_file+regions_layer" when both name the place)."""
    from dataclasses import replace

    groups: Dict[str, List[Region]] = {}
    for region in regions:
        groups.setdefault(region.name, []).append(region)
    merged = []
    for group in groups.values():
        chosen = next((r for r in group if r.source == "label_file"), group[0])
        sources = "+".join(dict.fromkeys(r.source for r in group))
        description = next((r.description for r in group if r.description), "")
        merged.append(replace(chosen, source=sources, description=description))
    return merged


@dataclass
class RankedRegion:
    region: Region
    score: float
    explanation: str


@dataclass
class Recommendation:
    """Ranked regions for a phrase. `matched` False: no labelled place matches the phrase
    (`results` empty; `closest` holds the best-scoring region anyway, `best_score` its score)."""

    phrase: str
    results: List[RankedRegion]
    oov_words: List[str] = field(default_factory=list)
    fallbacks: List[str] = field(default_factory=list)
    matched: bool = True
    best_score: float = float("nan")
    closest: List[RankedRegion] = field(default_factory=list)
    # How likely the first region is the place meant (0..1; nan: the ranking has no
    # calibration); `sure` False: below the confident level, the ranking is a best guess.
    confidence: float = float("nan")
    sure: bool = True
