"""The descriptions-never-hurt check of region search, shared by the tests of both backends
(test_embeddings_sentence.py: the sentence backend; test_fresh_start.py: the word2vec backend,
on the model its server trained), imported through the test conftest's sys.path entry."""
import json
from pathlib import Path

import numpy as np
import yaml

from region_search.labels import Region
from region_search.ranking import PlaceRecommender

WORKSPACE = Path(__file__).resolve().parents[3]
DATA = WORKSPACE / "bench" / "region_search" / "data"
DESCRIPTIONS = Path(__file__).resolve().parents[1] / "config" / "towne_levine_descriptions.yaml"


def evaluation_sets(shared_maps: Path) -> dict:
    """{set: (labels, {label: description}, [(phrase, expected labels)])}."""
    sets = {}
    for name, building in yaml.safe_load((DATA / "lobo_buildings.yaml").read_text())[
            "buildings"].items():
        labels = list(building.get("labels", []))
        if "labels_file" in building:
            labels += sorted(json.loads((shared_maps / building["labels_file"]).read_text()))
        labels += building.get("extra_labels", [])
        sets[name] = (labels, building["descriptions"],
                      [(q["phrase"], q["expected"]) for q in building["queries"]])
    test_2 = yaml.safe_load((DATA / "region_test_real_2.yaml").read_text())["buildings"]
    for name, building in test_2.items():
        labels = sorted(json.loads((shared_maps / building["labels_file"]).read_text()))
        sets[name] = (labels, yaml.safe_load(DESCRIPTIONS.read_text()),
                      [(q["phrase"], q["expected"]) for q in building["queries"]])
    return sets


class OnceFeatures:
    """The backend's evidence (SentenceFeatures / WordFeatures), each phrase's computed once per
    label set: `recommend` and `evidence` of the same phrase share it."""

    def __init__(self, features):
        self.features = features
        self._evidence = {}

    def set_regions(self, regions) -> None:
        self.features.set_regions(regions)
        self._evidence = {}

    def evidence(self, phrase: str):
        if phrase not in self._evidence:
            self._evidence[phrase] = self.features.evidence(phrase)
        return self._evidence[phrase]


def answers(recommender: PlaceRecommender, labels, descriptions, queries) -> list:
    """Per phrase: (right without descriptions, right with them, refused without, refused with,
    every label's score without, with). Right: top-1 among the expected labels, or "no place
    matches" when none is expected."""
    recommender.set_regions([Region(n, 0.0, 0.0, description=descriptions.get(n, ""))
                             for n in labels])
    out = []
    for phrase, expected in queries:
        with_them = recommender.recommend(phrase, top_k=1)
        evidence = recommender.evidence(phrase)
        own = recommender.scores(evidence, descriptions=False)
        described = recommender.scores(evidence, descriptions=True)
        top = evidence.names[int(np.argmax(own))]
        lead = float(np.max(own) - np.mean(own))
        refused = lead < recommender.weights.no_match_margin
        right_without = (not refused and top in expected) if expected else refused
        right_with = ((with_them.matched and with_them.results[0].region.name in expected)
                      if expected else not with_them.matched)
        out.append((right_without, right_with, refused, not with_them.matched, own, described))
    return out


def check_never_hurt(recommender, sets):
    """No label's score is lower with descriptions, no phrase is refused because of them, and
    over all sets at least as many phrases are answered right with them as without. (Top-1 may
    change within one set: another label's description may match a phrase better, as designed;
    the per-set counts are in the assertion message and in the accuracy bench.)"""
    totals, per_set = [0, 0], {}
    for name, (labels, descriptions, queries) in sets.items():
        rows = answers(recommender, labels, descriptions, queries)
        for (phrase, _), (_, _, refused, refused_with, own, described) in zip(queries, rows):
            assert np.all(described >= own - 1e-9), (name, phrase)
            assert refused or not refused_with, (name, phrase)
        per_set[name] = (sum(r[1] for r in rows), sum(r[0] for r in rows), len(rows))
        totals[0] += per_set[name][0]
        totals[1] += per_set[name][1]
    assert totals[0] >= totals[1], per_set
