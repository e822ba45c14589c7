"""The ranking that weighs evidence (region_search.ranking): descriptions never lower a score,
room numbers decide, "no labelled place matches", the shipped settings file (no ROS).

Word vectors: a hand-made space whose axes are meanings (as test_word_matching.py), so the
expected answers follow from the space, not from the code."""
import numpy as np
import pytest
from gensim.models import KeyedVectors

from region_search.corpora import WordNet
from region_search.embeddings import WordEmbeddings
from region_search.errors import EmptyPhraseError, LabelFileError, ModelLoadingError
from region_search.knowledge import PlaceKnowledge
from region_search.labels import Region
from region_search.ranking import (
    FEATURES,
    PlaceRecommender,
    RankingWeights,
    SentenceFeatures,
    WordFeatures,
    lead_and_gap,
    load_ranking_weights,
    specific_spelling,
)
from robot_common.errors import WorkspaceError

# Axes: drink, paper, motion, body, robots.
SPACE = {"coffee": [1, 0, 0, 0, 0], "cafe": [0.9, 0.1, 0, 0, 0], "print": [0, 1, 0, 0, 0],
         "printer": [0, 0.95, 0.05, 0, 0], "poster": [0.1, 0.9, 0, 0, 0],
         "room": [0.2, 0.2, 0.2, 0.2, 0.2], "elevator": [0, 0, 1, 0, 0],
         "lift": [0, 0, 0.95, 0, 0.05], "robot": [0, 0, 0.1, 0, 1], "robotics": [0, 0, 0, 0, 1],
         "laboratory": [0, 0.1, 0, 0.3, 0.6], "lab": [0, 0.1, 0, 0.3, 0.6],
         "snacks": [0.8, 0, 0, 0.2, 0], "drinks": [1, 0, 0, 0, 0], "dinner": [0.7, 0, 0, 0.3, 0],
         "vending": [0.6, 0.2, 0.2, 0, 0], "machines": [0.1, 0.2, 0.4, 0, 0.3]}
LABELS = ["printer_room", "cafe", "elevator", "grasp", "vending_machines", "towne_321",
          "towne_313"]
# Plain weights: name similarity and spelling count, a matching room number decides.
WEIGHTS = RankingWeights({"name": 3.0, "spelling": 1.0, "number_match": 4.0,
                          "number_mismatch": -4.0}, description_offset=0.2, no_match_margin=0.05)


@pytest.fixture
def embed():
    kv = KeyedVectors(vector_size=5)
    kv.add_vectors(list(SPACE), np.array(list(SPACE.values()), dtype=np.float32))
    return WordEmbeddings(kv, remove_components=-1).embed_words


def regions(descriptions=None):
    descriptions = descriptions or {}
    return [Region(n, float(i), 0.0, description=descriptions.get(n, ""))
            for i, n in enumerate(LABELS)]


def recommender(embed, descriptions=None, weights=WEIGHTS):
    ranker = PlaceRecommender(WordFeatures(embed), weights)
    ranker.set_regions(regions(descriptions))
    return ranker


def top(ranker, phrase):
    result = ranker.recommend(phrase, top_k=1)
    return result.results[0].region.name if result.matched else None


def test_names_spelling_and_room_numbers_rank_as_the_space_says(embed):
    ranker = recommender(embed)
    assert top(ranker, "print a poster") == "printer_room"
    assert top(ranker, "coffee") == "cafe"
    assert top(ranker, "the lift") == "elevator"
    assert top(ranker, "room 313") == "towne_313"  # the number decides, not "room"
    assert top(ranker, "room three twenty-one") == "towne_321"  # said as words
    with pytest.raises(EmptyPhraseError):
        ranker.recommend("  ?! ")


def test_a_description_adds_evidence_for_its_own_place_and_never_lowers_a_score(embed):
    plain = recommender(embed)
    described = recommender(embed, {"grasp": "the robotics laboratory",
                                    "vending_machines": "snacks and drinks"})
    assert top(plain, "the robotics lab") != "grasp"  # nothing in "grasp" says robots
    assert top(described, "the robotics lab") == "grasp"
    for phrase in ["the robotics lab", "eat dinner", "coffee", "print a poster",
                   "the lift", "room 313", "snacks"]:
        without = plain.scores(plain.evidence(phrase))
        with_them = described.scores(described.evidence(phrase))
        names = plain.features.labels.names
        assert np.all(with_them >= without - 1e-12), phrase
        changed = {names[i] for i in np.flatnonzero(with_them > without + 1e-12)}
        assert changed <= {"grasp", "vending_machines"}, (phrase, changed)


def test_a_description_that_matches_less_than_another_place_does_not_take_its_phrase(embed):
    # "coffee" is the cafe's own name word; the vending machines' "snacks and drinks" is close
    # to it in this space, but less than the cafe's name, so the cafe keeps it.
    described = recommender(embed, {"vending_machines": "snacks and drinks"})
    assert top(described, "coffee") == "cafe"


def test_no_labelled_place_matches_a_phrase_that_stands_out_nowhere(embed):
    ranker = recommender(embed)
    result = ranker.recommend("zebra giraffe", top_k=3)  # no word of it has a vector
    assert not result.matched and result.results == []
    assert len(result.closest) == 1 and result.closest[0].region.name in LABELS
    matched = ranker.recommend("printer", top_k=3)
    assert matched.matched and matched.results[0].region.name == "printer_room"
    always = recommender(embed, weights=RankingWeights(WEIGHTS.weights))  # no threshold
    assert always.recommend("zebra giraffe", top_k=3).matched


def test_name_spelling_counts_words_every_label_has_less():
    specificity = {"room": 0.1, "printer": 1.0}
    assert specific_spelling(["printer"], ["printer", "room"], specificity) == 1.0
    assert specific_spelling(["room"], ["printer", "room"], specificity) == pytest.approx(0.1)
    assert specific_spelling(["321"], ["towne", "321"], {}) == 0.0  # numbers: number features


@pytest.mark.wordnet
def test_place_knowledge_prefers_the_thing_or_place_sense_and_finds_compounds():
    knowledge = PlaceKnowledge(WordNet())
    printer = knowledge.text("printer_room")
    assert "output device that prints" in printer and "occupation" not in printer
    assert knowledge.text("cafeteria").startswith("cafeteria: a restaurant")
    assert "restaurant" in knowledge.kinds("cafeteria")
    breaks = knowledge.compound_texts("break_room")
    assert any(text.startswith("coffee break:") for text in breaks)
    assert knowledge.compound_texts("room") == []  # "room" is in too many compounds to say much


def test_the_shipped_settings_load_for_both_backends_and_bad_files_are_clear_errors(tmp_path):
    for backend in ("sentence", "word2vec"):
        weights = load_ranking_weights(backend)
        assert set(weights.weights) <= set(FEATURES) and weights.chosen_on
        assert weights.weights["number_match"] > 0 > weights.weights["number_mismatch"]
        assert np.isfinite(weights.no_match_margin)
    bad = tmp_path / "weights.yaml"
    bad.write_text("sentence: {weights: {colour: 1.0}}\n")
    with pytest.raises(LabelFileError, match="colour"):
        load_ranking_weights("sentence", bad)
    with pytest.raises(LabelFileError, match="word2vec"):
        load_ranking_weights("word2vec", bad)
    with pytest.raises(WorkspaceError, match="cannot read"):
        load_ranking_weights("sentence", tmp_path / "missing.yaml")


def test_a_place_named_by_the_label_file_and_the_regions_layer_is_one_entry(embed):
    ranker = PlaceRecommender(WordFeatures(embed), RankingWeights(WEIGHTS.weights))
    layer = [Region(n, 10.0 + i, 5.0, source="regions_layer")
             for i, n in enumerate(["printer_room", "cafe", "elevator", "printer_room"])]
    ranker.set_regions(regions() + layer)
    result = ranker.recommend("print a poster", top_k=3)
    names = [r.region.name for r in result.results]
    assert names[0] == "printer_room" and len(set(names)) == len(names) == 3, names
    printer = result.results[0].region
    assert printer.source == "label_file+regions_layer"
    assert (printer.x, printer.y) == (0.0, 0.0)  # the label file's pose (LABELS[0] at x 0)
    everything = [r.region.name for r in ranker.recommend("coffee", top_k=0).results]
    assert sorted(everything) == sorted(LABELS)
    layer_only = PlaceRecommender(WordFeatures(embed), RankingWeights(WEIGHTS.weights))
    layer_only.set_regions(layer)
    only = layer_only.recommend("print a poster", top_k=3).results
    assert [r.region.name for r in only][:1] == ["printer_room"] and len(only) == 3
    assert only[0].region.source == "regions_layer" and only[0].region.x == 10.0


class LoadingThenReady:
    """An embedding backend that is still loading for its first `loading` calls (raising as the
    embedding service's client does), then answers: the moment a node's backend becomes ready."""

    def __init__(self, embed, loading: int):
        self.embed, self.loading, self.calls = embed, loading, 0

    def __call__(self, words):
        self.calls += 1
        if self.calls <= self.loading:
            raise ModelLoadingError("embedding model still loading (test)")
        return self.embed(words)


@pytest.mark.parametrize("kind", ["word", "sentence"])
@pytest.mark.parametrize("loading", [1, 2, 3, 5, 8])
def test_labels_are_complete_after_the_backend_became_ready_in_the_middle_of_an_update(
        embed, kind, loading):
    backend = LoadingThenReady(embed, loading)
    features = WordFeatures(backend) if kind == "word" else SentenceFeatures(backend)
    ranker = PlaceRecommender(features, WEIGHTS)
    failed, published = 0, []
    for _ in range(loading + 1):
        try:
            ranker.set_regions(regions({"grasp": "the robotics laboratory"}))
            break
        except ModelLoadingError:
            failed += 1
            published.append(ranker.features.labels.names + [r.name for r in ranker.regions])
    assert failed >= 1 and backend.calls > loading
    for phrase in ("print a poster", "coffee", "room 313", "the robotics lab"):
        result = ranker.recommend(phrase, top_k=0)
        assert sorted(r.region.name for r in result.results) == sorted(LABELS), phrase
    assert published == [[]] * failed  # a failed update published nothing


def test_confidence_rises_with_the_lead_and_says_not_sure_below_its_level(embed):
    calibrated = RankingWeights(WEIGHTS.weights, no_match_margin=float("-inf"),
                                confidence=(-2.0, 4.0, 4.0), sure_confidence=0.5)
    assert calibrated.confidence_of(0.0, 0.0) == pytest.approx(1 / (1 + np.exp(2.0)))
    assert calibrated.confidence_of(1.0, 0.5) > calibrated.confidence_of(0.5, 0.1)
    assert np.isnan(WEIGHTS.confidence_of(1.0, 1.0))  # not calibrated
    assert lead_and_gap(np.array([3.0, 1.0, 2.0])) == (1.0, 1.0)
    ranker = recommender(embed, weights=calibrated)
    clear = ranker.recommend("printer", top_k=3)
    vague = ranker.recommend("zebra giraffe", top_k=3)  # no word has a vector: all tie
    assert clear.matched and clear.sure and clear.confidence > 0.5
    assert vague.matched and not vague.sure and vague.confidence < clear.confidence
    assert len(vague.results) == 3  # a best guess with its confidence, not an empty answer
