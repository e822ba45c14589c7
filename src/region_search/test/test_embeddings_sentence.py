"""The sentence backend (all-MiniLM-L6-v2, loaded once for this module), the phrase-level region
recommender on it, and the choice of backend with its fallback to word2vec (no ROS here)."""
import json
import subprocess
import sys

import numpy as np
import pytest

from region_search.backends import EmbeddingServerParams, load_backend
from region_search.corpora import WordNet
from region_search.errors import EmbeddingError, EmptyPhraseError, ModelError
from region_search.phrase import PhraseRegionRecommender
from region_search.recommender import Region
from region_search.sentence import check_model_dir, default_model_dir, load_sentence_model
from robot_sim.building import generate_building

# A tiny word2vec text file (the fallback's model): axes drink, motion.
VECTORS = "4 2\nwater 1 0\nfountain 0.9 0.1\nelevator 0 1\nlift 0.1 0.9\n"


@pytest.fixture(scope="module")
def sentence():
    return load_sentence_model(cache_size=50)


@pytest.fixture(scope="module")
def building_regions():
    return [Region(name, x, y) for name, (x, y) in sorted(generate_building(0).labels.items())]


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


@pytest.mark.wordnet
def test_phrase_recommender_finds_the_generated_buildings_places(sentence, building_regions):
    recommender = PhraseRegionRecommender(sentence.embed_phrases, wordnet=WordNet())
    recommender.set_regions(building_regions)
    assert recommender.label_text("water_fountain").startswith("water fountain: bubbler drinking")
    for phrase, best in [("where can I get a drink of water", "water_fountain"),
                         ("restroom", "bathroom"), ("take the lift", "elevator"),
                         ("microscope", "bio_lab"), ("somewhere to sit and relax", "lounge"),
                         ("office 202", "office_202"), ("classroom 101", "classroom_101")]:
        result = recommender.recommend(phrase, top_k=3)
        assert result.results[0].region.name == best, (phrase, result.results)
        assert result.results[0].score >= result.results[1].score >= result.results[2].score
    numbered = recommender.recommend("classroom 101", top_k=0).results
    assert "number 101 matches (+0.20)" in numbered[0].explanation
    assert "number 102 is not 101 (-0.20)" in next(r.explanation for r in numbered
                                                   if r.region.name == "classroom_102")
    typo = recommender.recommend("the printerz room", top_k=1)
    assert typo.results[0].region.name == "printer_room" and typo.oov_words == ["printerz"]
    assert "word pieces 'printer' + '##z'" in typo.fallbacks[0]
    with pytest.raises(EmptyPhraseError, match="has no words"):
        recommender.recommend(" . ")


@pytest.mark.wordnet
def test_numbers_as_text_only_confuse_rooms_that_differ_by_number(sentence, building_regions):
    """Why the number rule exists: without it, "classroom 101" is not reliably classroom_101."""
    # Name spelling off in both: it also matches "101" exactly (its own test below).
    plain = PhraseRegionRecommender(sentence.embed_phrases, wordnet=WordNet(), number_weight=0.0,
                                    name_spelling_weight=0.0)
    ruled = PhraseRegionRecommender(sentence.embed_phrases, wordnet=WordNet(),
                                    name_spelling_weight=0.0)
    gaps = []
    for recommender in (plain, ruled):
        recommender.set_regions(building_regions)
        scores = {r.region.name: r.score for r in recommender.recommend("classroom 101", 0).results}
        gaps.append(scores["classroom_101"] - scores["classroom_102"])
    assert gaps[0] < 0.05 and gaps[1] == pytest.approx(gaps[0] + 0.4, abs=1e-6)


@pytest.mark.wordnet
def test_name_share_and_spelling_find_the_real_floors_names(sentence, shared_data_dir):
    """Dev phrases (bench/data/region_eval_real.yaml) the phrase method missed before it had the
    bare-name share and the name-spelling match: WordNet's senses of "far" (FAR, an
    army) had drowned "levine far corner"."""
    labels = json.loads((shared_data_dir / "maps" / "towne_levine_labels.json").read_text())
    floor = [Region(name, pose["x"], pose["y"]) for name, pose in sorted(labels.items())]
    before = PhraseRegionRecommender(sentence.embed_phrases, wordnet=WordNet(),
                                     name_text_weight=0.0, name_spelling_weight=0.0)
    now = PhraseRegionRecommender(sentence.embed_phrases, wordnet=WordNet())
    for recommender in (before, now):
        recommender.set_regions(floor)
    for phrase, expected in (("the far corner of Levine", "levine_far_corner"),
                             ("Levine Hall corner", "levine_far_corner")):
        assert before.recommend(phrase, 1).results[0].region.name != expected
        best = now.recommend(phrase, 1).results[0]
        assert best.region.name == expected and "name spelled" in best.explanation


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
