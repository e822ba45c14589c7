"""Choosing region_search's ranking settings on some buildings (weights of the evidence, the
description offset, the no-match threshold) and scoring them on another.

- `fit_weights`: conditional logit over each phrase's labels (softmax of the weighted evidence,
  the expected label(s) as the answer), L2-penalised except the two number features (rare in any
  phrase set, but a room number that matches is decisive); phrases that match no place are not
  used here.
- `choose_threshold`: the no-match margin (the best label's score less the mean score of all
  labels): a low quantile of the margins of the training phrases that have a place, the largest
  quantile whose threshold, chosen on all training buildings but one, wrongly refuses at most
  FALSE_NO_MATCH_BUDGET of the phrases with a place of the building left out, for every
  building left out in turn (inner leave-one-building-out). A refusal of a phrase that has a
  place costs more than a best guess for one that has none (which comes with a low confidence).
- `fit_confidence`: the answer's confidence, a logistic regression of "the first label is a
  right answer" on the best label's lead over the mean and its gap to the second.
- `choose_sources`: whether to use WordNet's definitions and compounds (OPTIONAL_SOURCES), by an
  inner leave-one-building-out on the training buildings.
- `choose_offset`: the description offset (from a fixed grid, ties: the larger, the safer) that
  answers most training phrases right with their labels' descriptions, among those with which
  no training building answers fewer right with descriptions than without.
`Scored` holds one phrase's evidence; `evaluate` gives top-1 and no-match figures.
"""
from dataclasses import dataclass
from itertools import combinations
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import minimize

from region_search.ranking import FEATURES, RankingWeights, lead_and_gap

NUMBER_FEATURES = [FEATURES.index("number_match"), FEATURES.index("number_mismatch")]
# Knowledge sources whose use is itself a setting (chosen like the weights).
OPTIONAL_SOURCES = ("knowledge", "compounds", "query_words")
OFFSETS = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
L2 = 0.01
# The no-match answer: wrong refusals allowed on any held-out building, and the quantiles of
# answerable margins tried.
FALSE_NO_MATCH_BUDGET = 0.05
QUANTILES = (0.0, 0.005, 0.01, 0.02, 0.03, 0.04, 0.05, 0.07, 0.1)
SURE_CONFIDENCE = 0.5  # "sure" = more likely right than not (fixed, not chosen on data)


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


def _stacked(items: Sequence[Scored]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phrases with a place as padded arrays: evidence (phrases, labels, features), which
    labels exist, which are expected."""
    usable = [i for i in items if i.expected]
    width = max(len(i.own) for i in usable)
    x = np.zeros((len(usable), width, len(FEATURES)))
    exists = np.zeros((len(usable), width), dtype=bool)
    right = np.zeros((len(usable), width), dtype=bool)
    for k, item in enumerate(usable):
        x[k, :len(item.own)] = item.own
        exists[k, :len(item.own)] = True
        right[k, item.expected] = True
    return x, exists, right


def fit_weights(items: Sequence[Scored], l2: float = L2) -> Dict[str, float]:
    """Evidence weights by L2-penalised conditional logit on the phrases that have a place."""
    x, exists, right = _stacked(items)
    penalty = np.ones(len(FEATURES))
    penalty[NUMBER_FEATURES] = 0.0

    def loss(w):
        s = np.where(exists, x @ w, -np.inf)
        e = np.exp(s - s.max(axis=1, keepdims=True))
        total, hit = e.sum(axis=1), (e * right).sum(axis=1)
        p, q = e / total[:, None], e * right / (hit[:, None] + 1e-300)
        value = -np.mean(np.log(hit / total + 1e-12))
        grad = np.einsum("nl,nlf->f", p - q, x) / len(x)
        return value + l2 * (penalty * w) @ w, grad + 2 * l2 * penalty * w

    result = minimize(loss, np.ones(len(FEATURES)), jac=True, method="L-BFGS-B")
    return {name: float(v) for name, v in zip(FEATURES, result.x)}


def _answers(items, weights, descriptions):
    """(best score's lead over the mean score, has a place, top-1 right, gap to the second,
    top-3 right) per phrase."""
    out = []
    for item in items:
        s = scores(item, weights, descriptions)
        top = int(np.argmax(s))
        lead, gap = lead_and_gap(s)
        if descriptions and item.described is not None:  # as PlaceRecommender.recommend
            lead = max(lead, lead_and_gap(scores(item, weights, False))[0])
        top3 = set(np.argsort(-s)[:3].tolist())
        out.append((lead, bool(item.expected), top in item.expected, gap,
                    bool(top3 & set(item.expected))))
    return out


def _right(answers, threshold):
    return sum((has and hit and best >= threshold) or (not has and best < threshold)
               for best, has, hit, *_ in answers)


def _quantile_cut(leads: Sequence[float], q: float) -> float:
    """A threshold below which a share `q` of these margins falls (q 0: below all of them)."""
    ordered = np.sort(np.asarray(leads, dtype=np.float64))
    k = int(np.floor(q * len(ordered)))
    if k <= 0:
        return float(ordered[0] - 1e-6)
    return float((ordered[k - 1] + ordered[min(k, len(ordered) - 1)]) / 2)


def choose_threshold(items: Sequence[Scored], weights: RankingWeights) -> float:
    """The no-match threshold: the largest quantile (QUANTILES) of answerable phrases' margins
    whose inner leave-one-building-out wrong refusals stay within FALSE_NO_MATCH_BUDGET on every
    inner held-out building."""
    answers = _answers(items, weights, descriptions=False)
    buildings = [i.building for i in items]
    leads = {b: [a[0] for a, ib in zip(answers, buildings) if ib == b and a[1]]
             for b in dict.fromkeys(buildings)}
    chosen = 0.0
    for q in QUANTILES:
        worst = 0.0
        for held_out in leads:
            others = [v for b, vs in leads.items() if b != held_out for v in vs]
            cut = _quantile_cut(others, q)
            worst = max(worst, sum(v < cut for v in leads[held_out]) / len(leads[held_out]))
        if worst <= FALSE_NO_MATCH_BUDGET:
            chosen = q
    return _quantile_cut([v for vs in leads.values() for v in vs], chosen)


def fit_confidence(items: Sequence[Scored], weights: RankingWeights,
                   l2: float = L2) -> Tuple[float, float, float]:
    """(bias, lead, gap) of a logistic regression of "the first label is right" (a phrase
    without a place: never right) on the lead over the mean and the gap to the second."""
    answers = _answers(items, weights, descriptions=False)
    x = np.array([[1.0, a[0], a[3]] for a in answers])
    y = np.array([float(a[1] and a[2]) for a in answers])

    def loss(w):
        z = x @ w
        p = 1.0 / (1.0 + np.exp(-z))
        nll = np.mean(np.logaddexp(0.0, z) - y * z)
        return nll + l2 * w[1:] @ w[1:], x.T @ (p - y) / len(y) + 2 * l2 * np.r_[0.0, w[1:]]

    result = minimize(loss, np.zeros(3), jac=True, method="L-BFGS-B")
    return tuple(float(v) for v in result.x)


def choose_offset(items: Sequence[Scored], weights: RankingWeights) -> float:
    """The description offset answering most phrases right with descriptions (ties: larger),
    among the offsets with which no training building answers fewer phrases right with its
    descriptions than without (the largest offset when none qualifies)."""
    buildings = list(dict.fromkeys(i.building for i in items))
    without = {b: _right(_answers([i for i in items if i.building == b], weights, False),
                         weights.no_match_margin) for b in buildings}
    best, chosen = -1, OFFSETS[-1]
    for offset in OFFSETS:
        trial = RankingWeights(weights.weights, offset, weights.no_match_margin)
        per_building = {b: _right(_answers([i for i in items if i.building == b], trial, True),
                                  weights.no_match_margin) for b in buildings}
        if any(per_building[b] < without[b] for b in buildings):
            continue
        right = sum(per_building.values())
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
    weights.confidence = fit_confidence(items, weights)
    weights.sure_confidence = SURE_CONFIDENCE
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
            "top3_hits": sum(a[4] for a in with_place),
            "answered": _right(answers, threshold) / max(1, len(answers)),
            "no_match_recall": sum(a[0] < threshold for a in without) / max(1, len(without)),
            "false_no_match": sum(a[0] < threshold for a in with_place) / max(1, len(with_place)),
            "no_match_hits": sum(a[0] < threshold for a in without),
            "false_no_match_hits": sum(a[0] < threshold for a in with_place),
            **_sureness(answers, weights), "misses": misses}


def _sureness(answers, weights: RankingWeights) -> dict:
    """Counts of the confidence's verdicts on answered phrases (not refused): "sure" ones that
    were right / wrong, "not sure" ones that were right / wrong (wrong: a phrase without a place
    or a wrong first label); phrases without a place that got "no match" or "not sure"; and the
    Brier score of the confidence."""
    out = {"sure_right": 0, "sure_wrong": 0, "unsure_right": 0, "unsure_wrong": 0,
           "none_flagged": 0}
    brier = []
    for lead, has, hit, gap, _ in answers:
        confidence = weights.confidence_of(lead, gap)
        right = has and hit
        brier.append((confidence - right) ** 2)
        sure = not confidence < weights.sure_confidence
        out["none_flagged"] += not has and (lead < weights.no_match_margin or not sure)
        if lead < weights.no_match_margin:
            continue
        out[("sure_" if sure else "unsure_") + ("right" if right else "wrong")] += 1
    out["brier"] = float(np.mean(brier)) if brier else float("nan")
    return out
