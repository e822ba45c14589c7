"""The ranking's settings: evidence features, their weights, the description offset, the
no-match margin and the answer's confidence (`RankingWeights`), and the shipped settings file
region_search/ranking_weights.yaml (written by bench/region_search/nlp_region_accuracy.py)."""
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Tuple

import numpy as np

from region_search.errors import LabelFileError

__all__ = ["FEATURES", "RankingWeights", "load_ranking_weights", "DEFAULT_WEIGHTS_PATH",
           "lead_and_gap"]

FEATURES = ("name", "knowledge", "expanded", "compounds", "spelling", "number_match",
            "number_mismatch", "query_words")
DEFAULT_WEIGHTS_PATH = Path(__file__).resolve().parent / "ranking_weights.yaml"


@dataclass
class RankingWeights:
    """How evidence adds up to a label's score, and when nothing matches."""

    weights: Dict[str, float]
    description_offset: float = 0.0
    no_match_margin: float = float("-inf")
    chosen_on: str = ""
    # (bias, lead, gap) of the logistic confidence; () = not calibrated (confidence nan)
    confidence: Tuple[float, ...] = ()
    sure_confidence: float = 0.5

    def confidence_of(self, lead: float, gap: float) -> float:
        """How likely the best label is the place meant, from its lead over the mean score and
        its gap to the second best (nan without a calibration)."""
        if len(self.confidence) != 3:
            return float("nan")
        bias, a, b = self.confidence
        z = bias + a * lead + b * gap
        return 1.0 / (1.0 + math.exp(-z)) if z > -700 else 0.0

    def vector(self) -> np.ndarray:
        unknown = sorted(set(self.weights) - set(FEATURES))
        if unknown:
            raise LabelFileError(f"unknown ranking features {unknown}; known: {FEATURES}")
        return np.array([float(self.weights.get(name, 0.0)) for name in FEATURES])

    def as_dict(self) -> dict:
        return {"weights": {k: round(float(v), 4) for k, v in self.weights.items()},
                "description_offset": round(float(self.description_offset), 4),
                "no_match_margin": round(float(self.no_match_margin), 4),
                "confidence": [round(float(v), 4) for v in self.confidence],
                "sure_confidence": round(float(self.sure_confidence), 4),
                "chosen_on": self.chosen_on}


def load_ranking_weights(backend: str, path="") -> RankingWeights:
    """The weights of a backend ("sentence" or "word2vec") from a YAML file (default: the
    shipped region_search/ranking_weights.yaml); LabelFileError when missing or malformed."""
    import yaml

    path = Path(path) if path else DEFAULT_WEIGHTS_PATH
    try:
        data = yaml.safe_load(path.read_text())
        entry = data[backend]
        weights = RankingWeights({str(k): float(v) for k, v in entry["weights"].items()},
                                 float(entry.get("description_offset", 0.0)),
                                 float(entry.get("no_match_margin", float("-inf"))),
                                 str(entry.get("chosen_on", "")),
                                 tuple(float(v) for v in entry.get("confidence", ()) or ()),
                                 float(entry.get("sure_confidence", 0.5)))
        if weights.confidence and len(weights.confidence) != 3:
            raise ValueError(f"confidence needs 3 numbers (bias, lead, gap), got "
                             f"{list(weights.confidence)}")
        weights.vector()
        return weights
    except OSError as err:
        raise LabelFileError(f"cannot read ranking weights {path}: {err.strerror}") from err
    except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as err:
        raise LabelFileError(f"ranking weights {path} have no valid entry for backend "
                             f"{backend!r}: {err!r}") from err


def lead_and_gap(scores: np.ndarray) -> Tuple[float, float]:
    """The best score's lead over the mean score, and its gap to the second best (0 with
    one label; -inf, 0 with none): what the no-match answer and the confidence look at."""
    if len(scores) == 0:
        return float("-inf"), 0.0
    ordered = np.sort(np.asarray(scores, dtype=np.float64))[::-1]
    gap = float(ordered[0] - ordered[1]) if len(ordered) > 1 else 0.0
    return float(ordered[0] - np.mean(ordered)), gap
