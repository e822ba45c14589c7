"""Region recommender core: label files, WordNet label expansion, ranking on a hand-made vector
space with known answers, spelling similarity (no ROS)."""
import json

import numpy as np
import pytest
from gensim.models import KeyedVectors

from region_search.corpora import WordNet
from region_search.embeddings import WordEmbeddings
from region_search.errors import EmbeddingError, EmptyPhraseError, LabelFileError
from region_search.labels import Region, load_label_file, parse_labels
from region_search.text_similarity import (
    SpellingIndex,
    content_words,
    name_spelling_score,
    spelling_similarity,
    string_baseline_score,
    tokenize,
)
from region_search.word_matching import LabelExpander, WordMatcher
from robot_sim.building import generate_building

# Axes: drink, paper, motion, body, people. Each label word points along its meaning.
SPACE = {"coffee": [1, 0, 0, 0, 0], "cafe": [0.9, 0.1, 0, 0, 0], "print": [0, 1, 0, 0, 0],
         "printer": [0, 0.95, 0.05, 0, 0], "poster": [0.1, 0.9, 0, 0, 0],
         "room": [0.2, 0.2, 0.2, 0.2, 0.2], "elevator": [0, 0, 1, 0, 0],
         "lift": [0, 0, 0.95, 0, 0.05], "professor": [0, 0.2, 0, 0, 1],
         "faculty": [0, 0.1, 0, 0, 1], "offices": [0, 0.3, 0, 0, 0.7], "town": [0, 0, 0, 0.5, 0.5],
         "drinking": [0.9, 0, 0, 0.1, 0], "fountain": [0.8, 0, 0.1, 0.1, 0],
         "water": [0.9, 0, 0, 0.2, 0]}
LABELS = ["printer_room", "cafe", "elevator", "faculty_offices", "towne_321", "towne_313"]


@pytest.fixture(scope="module")
def wordnet():
    """One WordNet for the module (its index is read once; it only reads the files)."""
    return WordNet()


@pytest.fixture
def embed():
    kv = KeyedVectors(vector_size=5)
    kv.add_vectors(list(SPACE), np.array(list(SPACE.values()), dtype=np.float32))
    return WordEmbeddings(kv, remove_components=-1).embed_words


def regions(names):
    return [Region(name, float(i), 2.0 * i) for i, name in enumerate(names)]


def test_tokens_of_label_names_and_phrases():
    assert tokenize("Towne_321's bio-lab") == ["towne", "321", "bio", "lab"]
    assert tokenize("towne321") == ["towne", "321"]
    assert tokenize("men's toilet") == ["men", "toilet"]
    assert content_words("where is the printer?") == ["printer"]


def test_spelling_similarity_is_trigram_dice_and_numbers_match_only_exactly():
    # towne: #to tow own wne ne# ; town: #to tow own wn# -> 2 * 3 / (5 + 4)
    assert spelling_similarity("towne", "town") == pytest.approx(6 / 9)
    assert spelling_similarity("321", "321") == 1.0 and spelling_similarity("321", "313") == 0.0
    assert string_baseline_score(["towne", "321"], ["towne", "321"]) == 1.0
    index = SpellingIndex(["town", "tower", "gown", "42"])
    assert index.nearest("towne") == ("town", pytest.approx(6 / 9))
    assert index.nearest("zzzz") is None and index.nearest("42") is None


def test_name_spelling_score_counts_the_phrase_words_spelled_like_the_name():
    # "skirkanich" is the name; "hall" matches no name word; the name's "to" is a stop word.
    assert name_spelling_score(["skirkanich", "hall"], "to_skirkanich") == pytest.approx(0.5)
    # town ~ towne 6/9 (>= 0.6), 321 exactly; another number counts nothing.
    assert name_spelling_score(["town", "321"], "towne_321") == pytest.approx((6 / 9 + 1) / 2)
    assert name_spelling_score(["town", "311"], "towne_321") == pytest.approx(6 / 9 / 2)
    assert name_spelling_score(["town"], "towne_321", min_similarity=0.7) == 0.0
    assert name_spelling_score(["coffee"], "towne_321") == 0.0
    assert name_spelling_score([], "towne_321") == 0.0


def test_label_file_round_trip_with_the_generated_building(tmp_path):
    building = generate_building(0)
    path = tmp_path / "labels.json"
    path.write_text(building.labels_json())
    loaded = load_label_file(path)
    assert {r.name for r in loaded} == set(building.labels)
    for region in loaded:
        assert (region.x, region.y) == pytest.approx(building.labels[region.name])
        assert region.orientation == (0.0, 0.0, 0.0, 1.0) and region.source == "label_file"


@pytest.mark.parametrize("content, says", [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "expected a JSON object"),
    ('{"bio_lab": {"x": 1.0}}', "label 'bio_lab' needs numeric 'x' and 'y'"),
    ('{"bio_lab": {"x": 1, "y": 2, "orientation": [0, 0, 1]}}', "bad orientation"),
    ('{"__": {"x": 1, "y": 2}}', "has no letters or digits"),
])
def test_bad_label_files_are_clear_errors(tmp_path, content, says):
    path = tmp_path / "labels.json"
    path.write_text(content)
    with pytest.raises(LabelFileError, match=says):
        load_label_file(path)
    with pytest.raises(LabelFileError, match="cannot read label file"):
        load_label_file(tmp_path / "missing.json")


def test_ranking_follows_the_hand_made_space(embed):
    recommender = WordMatcher(embed)
    recommender.set_regions(regions(LABELS))
    for phrase, best in [("somewhere to print a poster", "printer_room"), ("I need coffee", "cafe"),
                         ("the lift", "elevator"), ("a professor's office", "faculty_offices"),
                         ("Towne 321", "towne_321"), ("room 313 in towne", "towne_313")]:
        result = recommender.recommend(phrase, top_k=2)
        assert [r.region.name for r in result.results][0] == best, (phrase, result)
        assert len(result.results) == 2
        assert result.results[0].score >= result.results[1].score
    everything = recommender.recommend("coffee", top_k=0).results
    assert len(everything) == len(LABELS)
    assert everything[0].region == Region("cafe", 1.0, 2.0)


def test_out_of_vocabulary_query_words_are_reported(embed):
    recommender = WordMatcher(embed)
    recommender.set_regions(regions(LABELS))
    result = recommender.recommend("towne 321")
    assert result.results[0].region.name == "towne_321"
    assert set(result.oov_words) == {"towne", "321"}
    assert any("spelled most alike 'town'" in note for note in result.fallbacks)
    assert any("321: a number" in note for note in result.fallbacks)
    assert "321~321 (name)" in result.results[0].explanation


def test_empty_phrase_and_bad_options_are_clear_errors(embed):
    recommender = WordMatcher(embed)
    recommender.set_regions(regions(LABELS))
    with pytest.raises(EmptyPhraseError, match="has no words"):
        recommender.recommend("  ?! ")
    with pytest.raises(EmbeddingError, match="unknown method 'best'"):
        WordMatcher(embed, method="best")


def test_duplicate_labels_at_several_places_are_all_returned(embed):
    recommender = WordMatcher(embed)
    recommender.set_regions([Region("cafe", 0, 0), Region("cafe", 5, 5), Region("elevator", 1, 1)])
    names = [(r.region.name, r.region.x) for r in recommender.recommend("coffee", 3).results]
    assert names == [("cafe", 0), ("cafe", 5), ("elevator", 1)]


@pytest.mark.wordnet
def test_wordnet_expansion_adds_synonyms_related_words_and_definitions(wordnet):
    expander = LabelExpander(wordnet)
    fountain = expander.expand("water_fountain")
    assert fountain["water"] == (1.0, "name")
    assert fountain["bubbler"][1] == "synonym 'bubbler' of water_fountain"
    assert fountain["drinking"][0] == 0.9
    vending = expander.expand("vending_machines")
    assert "selling" in vending and vending["selling"][0] == 0.6  # "a slot machine for selling goods"
    assert "print" in expander.expand("printer_room")
    assert set(expander.expand("towne_321")) == {"towne", "321"}  # nothing to expand


@pytest.mark.wordnet
def test_wordnet_synonyms_find_labels_the_vectors_alone_miss(embed, wordnet):
    plain = WordMatcher(embed)
    expanded = WordMatcher(embed, wordnet=wordnet)
    for recommender in (plain, expanded):
        recommender.set_regions(regions(["elevator", "lounge", "bio_lab"]))
    # "couch" has no vector; WordNet lists it as a synonym of lounge ("sofa, couch, lounge").
    assert expanded.recommend("couch").results[0].region.name == "lounge"
    assert plain.recommend("couch").results[0].score == 0.0
    # Without vectors at all, equal words (after expansion) still match.
    lexical = WordMatcher(None, wordnet=wordnet)
    lexical.set_regions(regions(["elevator", "lounge", "bio_lab"]))
    assert lexical.recommend("laboratory").results[0].region.name == "bio_lab"


def test_parse_labels_accepts_integers_and_z(tmp_path):
    (region,) = parse_labels(json.loads('{"lab": {"x": 1, "y": 2, "z": 3}}'))
    assert (region.x, region.y, region.z) == (1.0, 2.0, 3.0)


def test_hubness_correction_lowers_labels_that_match_everything(embed):
    plain, corrected = WordMatcher(embed), WordMatcher(embed, hubness=True)
    for recommender in (plain, corrected):
        recommender.set_regions(regions(["room", "elevator", "cafe", "printer"]))

    def score(recommender, label):
        return next(r.score for r in recommender.recommend("fountain", 0).results
                    if r.region.name == label)

    # "room" points equally along every axis, so it is fairly close to every other label's words;
    # "elevator" is close to none of them (cafe, printer, room: drink, paper, everything).
    drop_room = score(plain, "room") - score(corrected, "room")
    drop_elevator = score(plain, "elevator") - score(corrected, "elevator")
    assert drop_room > drop_elevator > 0
    assert "minus label hubness" in corrected.recommend("fountain", 1).results[0].explanation


@pytest.mark.wordnet
def test_a_share_of_the_word_score_is_the_label_name_alone(embed, wordnet):
    labels = regions(["printer_room", "cafe", "elevator", "water_fountain"])
    expanded = WordMatcher(embed, wordnet=wordnet, name_text_weight=0.0)
    names = WordMatcher(embed)
    shared = WordMatcher(embed, wordnet=wordnet, name_text_weight=0.25)
    for recommender in (expanded, names, shared):
        recommender.set_regions(labels)

    def scores(recommender, phrase):
        return {r.region.name: r.score for r in recommender.recommend(phrase, 0).results}

    for phrase in ("coffee", "drinking fountain", "a lift"):
        alone, wide, mixed = (scores(r, phrase) for r in (names, expanded, shared))
        for label in alone:
            assert mixed[label] == pytest.approx(0.75 * wide[label] + 0.25 * alone[label])
    assert "on the name alone" in shared.recommend("coffee", 1).results[0].explanation
    assert WordMatcher(embed).name_text_weight == 0.0  # no WordNet: names only anyway
