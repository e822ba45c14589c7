"""The sentence backend (all-MiniLM-L6-v2, loaded once for this module) and the choice of backend
with its fallback to word2vec (no ROS here); then the descriptions-never-hurt check of the
sentence backend, in this module so that PyTorch and sentence-transformers are imported once for
both (about 5 CPU-s each time). The shipped phrase-level ranking on it is checked through the
nodes (test_start_up.py: the generated building's places, room numbers, typos).

Label descriptions never make region search worse: for each backend, with the shipped ranking
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
import json
import subprocess
import sys

import numpy as np
import pytest
from region_search_never_hurt import OnceFeatures, check_never_hurt, evaluation_sets

from region_search.backends import EmbeddingServerParams, load_backend
from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords
from region_search.errors import EmbeddingError, EmptyPhraseError, ModelError
from region_search.labels import Region
from region_search.ranking import PlaceRecommender, SentenceFeatures, load_ranking_weights
from region_search.sentence import check_model_dir, default_model_dir, load_sentence_model, model_text
from region_search.text_similarity import spoken_numbers

# A tiny word2vec text file (the fallback's model): axes drink, motion.
VECTORS = "4 2\nwater 1 0\nfountain 0.9 0.1\nelevator 0 1\nlift 0.1 0.9\n"


@pytest.fixture(scope="module")
def sentence():
    return load_sentence_model(cache_size=50)


def test_phrase_vectors_are_unit_length_and_batches_equal_single_calls(sentence):
    embedded = sentence.embed_phrases(["water fountain", "drinking fountain", "elevator"])
    assert embedded.vectors.shape == (3, sentence.dimension) and sentence.dimension == 384
    assert np.allclose(np.linalg.norm(embedded.vectors, axis=1), 1.0, atol=1e-5)
    fountain, drinking, elevator = embedded.vectors
    assert fountain @ drinking > 0.7 > 0.3 > fountain @ elevator
    alone = sentence.embed_phrases(["drinking fountain"]).vectors[0]
    assert np.allclose(alone, drinking, atol=1e-5)
    assert list(embedded.weights) == [1.0, 1.0, 1.0] and embedded.oov == []
    # Underscored label names are read as words: "bio_lab" is "bio lab".
    assert np.allclose(sentence.embed_phrases(["bio_lab"]).vectors,
                       sentence.embed_phrases(["bio lab"]).vectors, atol=1e-6)


def test_vectors_are_cached_and_the_cache_is_bounded(sentence):
    misses = sentence.misses
    first = sentence.encode(["a phrase seen once", "another new phrase"])
    assert sentence.misses == misses + 2
    again = sentence.encode(["another new phrase"])
    assert sentence.misses == misses + 2 and np.array_equal(again[0], first[1])
    sentence.encode([f"filler phrase number {i}" for i in range(60)])
    assert len(sentence._cache) == 50  # cache_size of the fixture: the oldest went first
    sentence.encode(["a phrase seen once"])
    assert sentence.misses == misses + 2 + 60 + 1


def test_words_outside_the_vocabulary_are_reported_with_their_word_pieces(sentence):
    embedded = sentence.embed_phrases(["towne_321", "kitchen"])
    assert embedded.oov == ["towne"]  # "321" and "kitchen" are whole words of its vocabulary
    assert embedded.notes[0] == ("towne: not a whole word of the sentence model's vocabulary, "
                                 "encoded from word pieces 'town' + '##e'")
    assert embedded.notes[1] == ""


@pytest.mark.parametrize("phrase", ["", "   ", "?!"])
def test_empty_phrases_and_bad_methods_are_clear_errors(sentence, phrase):
    with pytest.raises(EmptyPhraseError, match="phrase 1: .*has no words"):
        sentence.embed_phrases(["water", phrase])
    with pytest.raises(EmptyPhraseError, match="candidate 0: .*has no words"):
        sentence.similarity("water", [phrase])
    with pytest.raises(EmbeddingError, match="unknown similarity method 'max'"):
        sentence.similarity("water", ["kitchen"], "max")


def test_similarity_ranks_candidates_by_meaning(sentence):
    candidates = ["kitchen", "printer room", "water fountain", "elevator"]
    for method in ("mean", "align"):
        for phrase, best in [("drinking water", "water fountain"), ("take the lift", "elevator"),
                             ("print a poster", "printer room"), ("cook dinner", "kitchen")]:
            scores, _ = sentence.similarity(phrase, candidates, method)
            assert candidates[int(np.argmax(scores))] == best, (method, phrase, scores)


def test_model_folders_without_a_model_are_clear_errors(tmp_path):
    assert check_model_dir(default_model_dir()) == default_model_dir()
    with pytest.raises(ModelError, match="no sentence model folder at '.*missing'"):
        load_sentence_model(str(tmp_path / "missing"))
    with pytest.raises(ModelError, match="holds no sentence-transformers model"):
        load_sentence_model(str(tmp_path))


def test_backend_falls_back_to_the_static_vectors_and_says_why(tmp_path):
    loaded = load_backend(EmbeddingServerParams(model_path=str(tmp_path)))
    assert loaded.backend == "static" and loaded.embeddings.backend == "static"
    assert loaded.note.startswith("fallback to static: sentence model unavailable: ")
    assert f"{tmp_path} holds no sentence-transformers model" in loaded.note
    assert loaded.embeddings.dimension == 256
    scores, _ = loaded.embeddings.similarity("the lift", ["water fountain", "elevator"])
    assert scores[1] > scores[0]
    with pytest.raises(ModelError, match=r"sentence model unavailable \(fallback disabled\)"):
        load_backend(EmbeddingServerParams(model_path=str(tmp_path), fallback=False))
    (tmp_path / "vectors.txt").write_text(VECTORS)
    explicit = load_backend(EmbeddingServerParams(
        backend="word2vec", model_path=str(tmp_path / "vectors.txt"),
        cache_dir=str(tmp_path / "cache"), remove_components=-1))
    assert explicit.backend == "word2vec" and explicit.note == "" and len(explicit.embeddings) == 4
    with pytest.raises(ModelError, match="unknown embedding backend 'glove'"):
        load_backend(EmbeddingServerParams(backend="glove"))


BLOCK_TORCH = """
import json, sys


class Missing:  # an import hook that finds none of these packages, as on a robot without them
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in sys.argv[3].split(","):
            raise ModuleNotFoundError(f"No module named {name!r}")


sys.meta_path.insert(0, Missing())
from region_search.backends import EmbeddingServerParams, load_backend

b = load_backend(EmbeddingServerParams(source="pretrained", pretrained_path=sys.argv[1],
                               cache_dir=sys.argv[2], remove_components=-1))
print(json.dumps({"backend": b.backend, "note": b.note, "torch": "torch" in sys.modules}))
"""


def _load_without(packages: str, tmp_path) -> dict:
    (tmp_path / "vectors.txt").write_text(VECTORS)
    out = subprocess.run([sys.executable, "-c", BLOCK_TORCH, str(tmp_path / "vectors.txt"),
                          str(tmp_path / "cache"), packages], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_without_pytorch_the_backend_falls_back_to_static_vectors_then_word2vec(tmp_path):
    """A robot without PyTorch (Python 3.8 robots), and one without the static vectors either.
    The test cannot uninstall packages from the shared venv, so a child process gets an import
    hook that finds no such module."""
    result = _load_without("torch", tmp_path)
    assert result["backend"] == "static" and not result["torch"]
    assert result["note"] == ("fallback to static: sentence model unavailable: cannot import "
                              "the sentence model's libraries (torch, sentence-transformers): "
                              "No module named 'torch'")
    result = _load_without("torch,wordllama", tmp_path)
    assert result["backend"] == "word2vec" and not result["torch"]
    assert result["note"].startswith("fallback to word2vec: sentence model unavailable: cannot ")
    assert result["note"].endswith("; static model unavailable: the static phrase vectors are "
                                   "not installed (pip package wordllama)")


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


@pytest.mark.wordnet
def test_descriptions_never_hurt_the_sentence_backend(wordnet, sets):
    model = load_sentence_model()
    # All phrases and label texts first (the model's cache then has them: the same vectors as
    # one call per text, at a fraction of the CPU); the recommender reads numbers said as words.
    encode_by_length(model, [spoken_numbers(phrase) for _, _, queries in sets.values()
                             for phrase, _ in queries] + label_texts(sets, wordnet))
    recommender = PlaceRecommender(OnceFeatures(SentenceFeatures(model.embed_phrases, wordnet)),
                                   load_ranking_weights("sentence"))
    check_never_hurt(recommender, sets)
