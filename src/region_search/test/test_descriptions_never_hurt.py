"""Label descriptions never make region search worse: for each backend, with the shipped ranking
settings, no label's score is lower with descriptions, no phrase is refused ("no labelled place
matches") because of them, and over all evaluation sets at least as many phrases are answered
right with them as without (no ROS).

Evaluation sets: the seven buildings of bench/region_search/data/lobo_buildings.yaml (each one its
own set) and the real floor's held-out set region_test_real_2.yaml with the floor's descriptions
(config/towne_levine_descriptions.yaml). The expected labels were written by hand before any
model ran on them. The sentence backend is the real all-MiniLM-L6-v2 (here); the word2vec backend
is checked in test_fresh_start.py, on the model (WordNet's glosses, 2 epochs instead of 15) that
test's embedding server trained from nothing: the suite trains it once. The check itself is in
region_search_never_hurt.py. The shipped models' figures with and without descriptions are the
accuracy bench's.

Each phrase's evidence is computed once per label set and used both for the answer
(`PlaceRecommender.recommend`) and for the scores with and without descriptions
(`OnceFeatures`: the evidence depends only on the phrase and the published label set).

The sentence model encodes all texts first, in batches of texts of about the same number of
tokens (`encode_by_length`): the vectors are the model's, with far less padding than batches of
each label set's texts as they come (about two thirds of the CPU).
"""
import numpy as np
import pytest
from region_search_never_hurt import OnceFeatures, check_never_hurt, evaluation_sets

from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords
from region_search.labels import Region
from region_search.ranking import PlaceRecommender, SentenceFeatures, load_ranking_weights
from region_search.sentence import load_sentence_model, model_text
from region_search.text_similarity import spoken_numbers

pytestmark = pytest.mark.wordnet

BATCH = 128  # texts per model call, sorted by their number of tokens


def label_texts(sets, wordnet) -> list:
    """Every text of the sets' labels that SentenceFeatures encodes (recorded, none encoded)."""
    texts = []

    def record(phrases):
        texts.extend(phrases)
        return EmbeddedWords(list(phrases), np.zeros((len(phrases), 1)), np.ones(len(phrases)))

    features = SentenceFeatures(record, wordnet)
    for labels, descriptions, _ in sets.values():
        features.set_regions([Region(n, 0.0, 0.0, description=descriptions.get(n, ""))
                              for n in labels])
    return texts


def encode_by_length(model, phrases) -> None:
    """The phrases' vectors into the model's cache, in batches of similar token counts."""
    tokens = model.tokenizer([model_text(p) for p in phrases])["input_ids"]
    order = sorted(range(len(phrases)), key=lambda i: len(tokens[i]))
    for start in range(0, len(order), BATCH):
        model.embed_phrases([phrases[i] for i in order[start:start + BATCH]])


@pytest.fixture(scope="module")
def wordnet():
    return WordNet()


@pytest.fixture(scope="module")
def sets(shared_data_dir):
    return evaluation_sets(shared_data_dir / "maps")


def test_descriptions_never_hurt_the_sentence_backend(wordnet, sets):
    model = load_sentence_model()
    # All phrases and label texts first (the model's cache then has them: the same vectors as
    # one call per text, at a fraction of the CPU); the recommender reads numbers said as words.
    encode_by_length(model, [spoken_numbers(phrase) for _, _, queries in sets.values()
                             for phrase, _ in queries] + label_texts(sets, wordnet))
    recommender = PlaceRecommender(OnceFeatures(SentenceFeatures(model.embed_phrases, wordnet)),
                                   load_ranking_weights("sentence"))
    check_never_hurt(recommender, sets)
