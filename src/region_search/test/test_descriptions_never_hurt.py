"""Label descriptions never make region search worse: for each backend, with the shipped ranking
settings, top-1 with descriptions >= without on every evaluation set (no ROS).

Evaluation sets: the seven buildings of bench/region_search/data/lobo_buildings.yaml (each one its
own set) and the real floor's held-out set region_test_real_2.yaml with the floor's descriptions
(config/towne_levine_descriptions.yaml). The expected labels were written by hand before any
model ran on them. The sentence backend is the real all-MiniLM-L6-v2; the word2vec backend is
word2vec trained here on WordNet's glosses with 2 epochs instead of 15 (the same training, 7x
shorter; the suite must stay short).
"""
import json
from pathlib import Path

import pytest
import yaml

from region_search.corpora import WordNet
from region_search.ranking import PlaceRecommender, SentenceFeatures, WordFeatures, load_ranking_weights
from region_search.recommender import Region
from region_search.sentence import load_sentence_model
from region_search.training import Word2VecParams, load_embeddings

pytestmark = pytest.mark.wordnet

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


def right_answers(recommender: PlaceRecommender, labels, descriptions, queries) -> int:
    """Phrases answered right: top-1 among the expected labels, or "no place matches" when
    none is expected."""
    recommender.set_regions([Region(n, 0.0, 0.0, description=descriptions.get(n, ""))
                             for n in labels])
    right = 0
    for phrase, expected in queries:
        result = recommender.recommend(phrase, top_k=1)
        if expected:
            right += result.matched and result.results[0].region.name in expected
        else:
            right += not result.matched
    return right


@pytest.fixture(scope="module")
def wordnet():
    return WordNet()


@pytest.fixture(scope="module")
def sets(shared_data_dir):
    return evaluation_sets(shared_data_dir / "maps")


def check_never_hurt(recommender, sets):
    for name, (labels, descriptions, queries) in sets.items():
        without = right_answers(recommender, labels, {}, queries)
        with_them = right_answers(recommender, labels, descriptions, queries)
        assert with_them >= without, (name, with_them, without, len(queries))


def test_descriptions_never_hurt_the_sentence_backend(wordnet, sets):
    model = load_sentence_model()
    recommender = PlaceRecommender(SentenceFeatures(model.embed_phrases, wordnet),
                                   load_ranking_weights("sentence"))
    check_never_hurt(recommender, sets)


def test_descriptions_never_hurt_the_word2vec_backend(wordnet, sets, tmp_path_factory):
    model, _ = load_embeddings("wordnet", params=Word2VecParams(epochs=2),
                               cache_dir=tmp_path_factory.mktemp("word2vec"))
    recommender = PlaceRecommender(WordFeatures(model.embed_words, wordnet),
                                   load_ranking_weights("word2vec"))
    check_never_hurt(recommender, sets)
