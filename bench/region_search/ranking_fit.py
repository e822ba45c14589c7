"""Choosing region_search's ranking settings on some buildings (weights of the evidence, the
description offset, the no-match threshold) and scoring them on another.

- `fit_weights`: conditional logit over each phrase's labels (softmax of the weighted evidence,
  the expected label(s) as the answer), L2-penalised except the two number features (rare in any
  phrase set, but a room number that matches is decisive); phrases that match no place are not
  used here.
- `choose_threshold`: the no-match margin (the best label's score less the mean score of all
  labels) that answers most training phrases right (a phrase with a place: top-1 right and its
  margin at least the threshold; a phrase without: below it), the middle of the best interval.
- `choose_sources`: whether to use WordNet's definitions and compounds (OPTIONAL_SOURCES), by an
  inner leave-one-building-out on the training buildings.
- `choose_offset`: the description offset (from a fixed grid, ties: the larger, the safer) that
  answers most training phrases right with their labels' descriptions.
`Scored` holds one phrase's evidence; `evaluate` gives top-1 and no-match figures.
"""
from dataclasses import dataclass
from itertools import combinations
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import minimize

from region_search.ranking import FEATURES, RankingWeights

NUMBER_FEATURES = [FEATURES.index("number_match"), FEATURES.index("number_mismatch")]
# Knowledge sources whose use is itself a setting (chosen like the weights).
OPTIONAL_SOURCES = ("knowledge", "compounds")
OFFSETS = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
L2 = 0.01


@dataclass
class Scored:
    """One phrase of a building: its evidence rows and the expected label indices."""

    building: str
    phrase: str
    expected: List[int]
    own: np.ndarray
    described: Optional[np.ndarray]
    names: List[str]


def scores(item: Scored, weights: RankingWeights, descriptions: bool) -> np.ndarray:
    w = weights.vector()
    own = item.own @ w
    if descriptions and item.described is not None:
        return np.maximum(own, item.described @ w - weights.description_offset)
    return own


def fit_weights(items: Sequence[Scored], l2: float = L2) -> Dict[str, float]:
    """Evidence weights by L2-penalised conditional logit on the phrases that have a place."""
    usable = [(i.own, i.expected) for i in items if i.expected]
    penalty = np.ones(len(FEATURES))
    penalty[NUMBER_FEATURES] = 0.0

    def loss(w):
        total, grad = 0.0, np.zeros_like(w)
        for rows, expected in usable:
            s = rows @ w
            p = np.exp(s - s.max())
            p /= p.sum()
            right = p[expected].sum()
            total -= np.log(right + 1e-12)
            grad -= p[expected] @ rows[expected] / (right + 1e-12) - p @ rows
        n = len(usable)
        return total / n + l2 * (penalty * w) @ w, grad / n + 2 * l2 * penalty * w

    result = minimize(loss, np.ones(len(FEATURES)), jac=True, method="L-BFGS-B")
    return {name: float(v) for name, v in zip(FEATURES, result.x)}


def _answers(items, weights, descriptions):
    """(best score's lead over the mean score, has a place, top-1 right) per phrase."""
    out = []
    for item in items:
        s = scores(item, weights, descriptions)
        top = int(np.argmax(s))
        out.append((float(s[top] - s.mean()), bool(item.expected), top in item.expected))
    return out


def _right(answers, threshold):
    return sum((has and hit and best >= threshold) or (not has and best < threshold)
               for best, has, hit in answers)


def choose_threshold(items: Sequence[Scored], weights: RankingWeights) -> float:
    """The no-match threshold answering most phrases right (middle of the best interval)."""
    answers = _answers(items, weights, descriptions=False)
    bests = sorted({a[0] for a in answers})
    cuts = [bests[0] - 1.0] + [(a + b) / 2 for a, b in zip(bests, bests[1:])] + [bests[-1] + 1.0]
    right = [_right(answers, cut) for cut in cuts]
    top = max(right)
    best_cuts = [c for c, r in zip(cuts, right) if r == top]
    return float(np.median(best_cuts)) if len(best_cuts) % 2 else float(
        best_cuts[len(best_cuts) // 2])


def choose_offset(items: Sequence[Scored], weights: RankingWeights) -> float:
    """The description offset answering most phrases right with descriptions (ties: larger)."""
    best, chosen = -1, OFFSETS[-1]
    for offset in OFFSETS:
        trial = RankingWeights(weights.weights, offset, weights.no_match_margin)
        right = _right(_answers(items, trial, descriptions=True), weights.no_match_margin)
        if right >= best:
            best, chosen = right, offset
    return chosen


def _without(items: Sequence[Scored], dropped: Sequence[str]) -> List[Scored]:
    """The items with the evidence of the `dropped` features zeroed (that source unused)."""
    columns = [FEATURES.index(name) for name in dropped]

    def zeroed(rows):
        if rows is None:
            return None
        rows = rows.copy()
        rows[:, columns] = 0.0
        return rows
    return [Scored(i.building, i.phrase, i.expected, zeroed(i.own), zeroed(i.described), i.names)
            for i in items]


def choose_sources(items: Sequence[Scored]) -> Tuple[str, ...]:
    """Which optional knowledge sources to use: the choice of OPTIONAL_SOURCES whose weights,
    fitted on all but one building, rank the left-out building best (forced top-1, summed
    over the buildings of `items`; ties: fewer sources)."""
    buildings = list(dict.fromkeys(i.building for i in items))
    best, chosen = -1, OPTIONAL_SOURCES
    for size in range(len(OPTIONAL_SOURCES), -1, -1):
        for used in combinations(OPTIONAL_SOURCES, size):
            trial = _without(items, [s for s in OPTIONAL_SOURCES if s not in used])
            hits = 0
            for held_out in buildings:
                weights = RankingWeights(fit_weights([i for i in trial if i.building != held_out]))
                hits += evaluate([i for i in trial if i.building == held_out], weights,
                                 descriptions=False)["top1_hits"]
            if hits >= best:
                best, chosen = hits, used
    return tuple(chosen)


def choose(items: Sequence[Scored], chosen_on: str) -> RankingWeights:
    """All settings, chosen on `items` only: knowledge sources (inner leave-one-building-out),
    evidence weights, no-match margin, description offset."""
    used = choose_sources(items)
    items = _without(items, [s for s in OPTIONAL_SOURCES if s not in used])
    fitted = fit_weights(items)
    weights = RankingWeights({k: v for k, v in fitted.items()
                              if k not in OPTIONAL_SOURCES or k in used}, chosen_on=chosen_on)
    weights.no_match_margin = choose_threshold(items, weights)
    weights.description_offset = choose_offset(items, weights)
    return weights


def evaluate(items: Sequence[Scored], weights: RankingWeights, descriptions: bool) -> dict:
    """top1: forced top-1 on the phrases with a place; answered: share of all phrases answered
    right with the no-match answer; no_match_recall: phrases without a place answered so;
    false_no_match: phrases with a place answered "no place matches"."""
    answers = _answers(items, weights, descriptions)
    threshold = weights.no_match_margin
    with_place = [a for a in answers if a[1]]
    without = [a for a in answers if not a[1]]
    misses = [{"building": i.building, "phrase": i.phrase,
               "expected": [i.names[e] for e in i.expected],
               "got": i.names[int(np.argmax(scores(i, weights, descriptions)))]
               if a[0] >= threshold else "(no match)"}
              for i, a in zip(items, answers)
              if not ((a[1] and a[2] and a[0] >= threshold) or (not a[1] and a[0] < threshold))]
    return {"n_place": len(with_place), "n_none": len(without),
            "top1": sum(a[2] for a in with_place) / max(1, len(with_place)),
            "top1_hits": sum(a[2] for a in with_place),
            "answered": _right(answers, threshold) / max(1, len(answers)),
            "no_match_recall": sum(a[0] < threshold for a in without) / max(1, len(without)),
            "false_no_match": sum(a[0] < threshold for a in with_place) / max(1, len(with_place)),
            "misses": misses}
