"""From region_search's answer to a goal, without ROS: go only where region_search is sure."""
import math
from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

__all__ = ["PlaceChoice", "choose_place"]


@dataclass
class PlaceChoice:
    """The place a phrase means, and whether to drive there (`sure`)."""

    sure: bool
    message: str
    label: str = ""
    pose: Tuple[float, float, float] = (0.0, 0.0, 0.0)   # x, y, yaw in region_search's frame
    confidence: float = math.nan
    candidates: List[str] = field(default_factory=list)
    scores: List[float] = field(default_factory=list)


def choose_place(phrase: str, *, success: bool, message: str, matched: bool,
                 labels: Sequence[str], scores: Sequence[float],
                 poses: Sequence[Tuple[float, float, float]], confidence: float,
                 min_confidence: float = 0.0) -> PlaceChoice:
    """The goal for `phrase` from a RecommendRegion answer's fields.

    Sure means: region_search answered, matched a place and did not call it a best guess (its
    message does not start with "not sure", its calibrated confidence level), and the
    confidence is at least `min_confidence` (0: region_search's own level decides). Otherwise
    the choice is not sure and names the candidates, and nothing should be driven to."""
    candidates, ranked = list(labels), [float(s) for s in scores]
    if not success:
        return PlaceChoice(False, f"region_search could not answer {phrase!r}: {message}")
    if not matched or not candidates:
        return PlaceChoice(False, message or f"no labelled place matches {phrase!r}",
                           confidence=confidence, candidates=candidates, scores=ranked)
    unsure = message.lower().startswith("not sure")
    if not unsure and not math.isnan(confidence) and confidence < min_confidence:
        unsure, message = True, (f"not sure (confidence {confidence:.2f}, below the errand "
                                 f"server's {min_confidence:.2f})")
    if unsure:
        listed = ", ".join(candidates[:5])
        return PlaceChoice(False, f"{message}; candidates: {listed}", label=candidates[0],
                           pose=tuple(poses[0]), confidence=confidence, candidates=candidates,
                           scores=ranked)
    return PlaceChoice(True, f"going to {candidates[0]}", label=candidates[0],
                       pose=tuple(poses[0]), confidence=confidence, candidates=candidates,
                       scores=ranked)
