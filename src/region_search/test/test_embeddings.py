"""Word vectors: fallbacks for missing words, phrase similarity, reproducible cached training,
and pretrained files (word2vec text/binary, gensim .kv) loaded memory-mapped."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from gensim.models import KeyedVectors

from region_search.corpora import DEFAULT_WORDNET_DIR
from region_search.embeddings import WordEmbeddings, phrase_tokens
from region_search.errors import EmbeddingError, EmptyPhraseError, ModelError
from region_search.training import (
    Word2VecParams,
    cached_word2vec,
    load_embeddings,
    load_pretrained,
    train_word2vec,
)

WORDNET = Path(DEFAULT_WORDNET_DIR)

# A hand-made vector space with known answers (unit axes: drink, paper, motion, body).
SPACE = {
    "coffee": [1, 0, 0, 0], "cafe": [0.9, 0.1, 0, 0], "water": [0.8, 0, 0, 0.2],
    "fountain": [0.7, 0, 0.1, 0.2], "print": [0, 1, 0, 0], "printer": [0.05, 0.95, 0, 0],
    "poster": [0, 0.8, 0, 0.1], "room": [0.3, 0.3, 0.3, 0.3], "mail": [0, 0.7, 0.3, 0],
    "elevator": [0, 0, 1, 0], "lift": [0, 0.05, 0.95, 0], "stairs": [0, 0, 0.8, 0.2],
    "town": [0.1, 0.1, 0.1, 0.1], "wash": [0.2, 0, 0, 0.9], "bathroom": [0.1, 0, 0, 1],
    "the": [0.5, 0.5, 0.5, 0.5],
}


def hand_made_vectors() -> KeyedVectors:
    kv = KeyedVectors(vector_size=4)
    kv.add_vectors(list(SPACE), np.array(list(SPACE.values()), dtype=np.float32))
    return kv


@pytest.fixture
def embeddings():
    counts = np.array([1000 if w == "the" else 10 for w in SPACE])
    return WordEmbeddings(hand_made_vectors(), counts=counts, remove_components=-1)


def test_words_in_the_vocabulary_have_no_note_and_frequent_words_weigh_less(embeddings):
    vector, note, weight = embeddings.word_vector("coffee")
    assert note == "" and np.isclose(np.linalg.norm(vector), 1.0)
    assert embeddings.weight("the") < embeddings.weight("coffee") < embeddings.weight("unknown") == 1


@pytest.mark.parametrize("word, says", [
    ("printers", "base form 'printer'"),
    ("mailroom", "sub-words 'mail' + 'room'"),
    ("towne", "spelled most alike 'town'"),
    ("321", "a number, matched by spelling only"),
    ("xyzzyq", "no vector"),
])
def test_out_of_vocabulary_words_fall_back_and_say_so(embeddings, word, says):
    vector, note, _ = embeddings.word_vector(word)
    assert says in note and note.startswith(word)
    assert (vector is None) == (word in ("321", "xyzzyq"))
    words = embeddings.embed_words([word, "coffee"])
    assert words.oov == [word] and words.notes[1] == ""


def test_compound_vector_is_the_mean_direction_of_its_parts(embeddings):
    vector, _, _ = embeddings.word_vector("mailroom")
    mail, room = (np.array(SPACE[w]) / np.linalg.norm(SPACE[w]) for w in ("mail", "room"))
    expected = (mail + room) / np.linalg.norm(mail + room)
    assert np.allclose(vector, expected)


@pytest.mark.parametrize("phrase", ["", "   ", "!!! ...", "_"])
def test_an_empty_phrase_is_a_clear_error(embeddings, phrase):
    with pytest.raises(EmptyPhraseError, match="has no words"):
        embeddings.embed_phrase(phrase)
    with pytest.raises(EmptyPhraseError, match="candidate 1: .*has no words"):
        embeddings.similarity("coffee", ["cafe", phrase])
    with pytest.raises(EmptyPhraseError, match="no candidates"):
        embeddings.similarity("coffee", [])


def test_phrases_of_several_words_and_label_names_rank_as_the_space_says(embeddings):
    candidates = ["printer_room", "cafe", "elevator", "bathroom"]
    for method in ("mean", "align"):
        for phrase, best in [("somewhere to print a poster", "printer_room"),
                             ("I need coffee", "cafe"), ("the lift", "elevator"),
                             ("wash", "bathroom")]:
            scores, _ = embeddings.similarity(phrase, candidates, method)
            assert candidates[int(np.argmax(scores))] == best, (method, phrase, scores)
    with pytest.raises(EmbeddingError, match="unknown similarity method 'max'"):
        embeddings.similarity("coffee", ["cafe"], "max")


def test_stop_words_are_dropped_unless_the_phrase_has_nothing_else():
    assert phrase_tokens("where is the Towne_321 lab?") == ["towne", "321", "lab"]
    assert phrase_tokens("where is it") == ["where", "is", "it"]


def test_common_direction_removal_centres_the_vectors():
    kv = hand_made_vectors()
    centred = WordEmbeddings(kv, remove_components=0)
    assert np.allclose(centred.mean_, np.asarray(kv.vectors).mean(axis=0))
    pca = WordEmbeddings(kv, remove_components=1)
    vector, _, _ = pca.word_vector("coffee")
    assert abs(vector @ pca.components_[0]) < 1e-9  # the top direction is gone


SENTENCES = [["the", "robot", "drives", "to", "the", "kitchen", "for", "coffee"],
             ["the", "printer", "is", "in", "the", "printer", "room"],
             ["people", "drink", "water", "at", "the", "water", "fountain"],
             ["the", "elevator", "goes", "to", "the", "next", "floor"]] * 30


def test_two_trainings_give_identical_vectors_whatever_the_hash_seed(tmp_path):
    params = Word2VecParams(vector_size=16, min_count=1, epochs=3)
    kv_a, counts_a = train_word2vec(SENTENCES, params)
    kv_b, _ = train_word2vec(SENTENCES, params)
    assert kv_a.index_to_key == kv_b.index_to_key
    assert np.array_equal(kv_a.vectors, kv_b.vectors)
    assert counts_a[kv_a.key_to_index["the"]] == 7 * 30
    # Python salts str hashes per process: a different PYTHONHASHSEED must not change anything.
    script = ("import json,sys,numpy as np;from region_search.training import *;"
              f"kv,_=train_word2vec(json.load(open({str(tmp_path / 's.json')!r})),"
              "Word2VecParams(vector_size=16,min_count=1,epochs=3));"
              f"np.save({str(tmp_path / 'v.npy')!r},kv.vectors)")
    (tmp_path / "s.json").write_text(json.dumps(SENTENCES))
    for seed in ("1", "12345"):
        subprocess.run([sys.executable, "-c", script], check=True,
                       env=dict(os.environ, PYTHONHASHSEED=seed))
        assert np.array_equal(np.load(tmp_path / "v.npy"), kv_a.vectors)
    other, _ = train_word2vec(SENTENCES, Word2VecParams(vector_size=16, min_count=1, epochs=3,
                                                         seed=2))
    assert not np.array_equal(other.vectors, kv_a.vectors)


@pytest.fixture(scope="module")
def tiny_wordnet(tmp_path_factory):
    """The first 400 synsets of each WordNet part of speech (a small, real gloss corpus)."""
    if not (WORDNET / "data.noun").is_file():
        pytest.skip("Debian's wordnet-base is not installed")
    folder = tmp_path_factory.mktemp("tiny_wordnet")
    for name in ("noun", "verb", "adj", "adv"):
        lines = (WORDNET / f"data.{name}").read_bytes().splitlines(keepends=True)
        synsets = [line for line in lines if not line.startswith(b"  ")][:400]
        (folder / f"data.{name}").write_bytes(b"".join(synsets))
    return folder


def test_cached_training_trains_once_then_loads_memory_mapped(tiny_wordnet, tmp_path):
    params = Word2VecParams(vector_size=16, epochs=2)
    first, info = cached_word2vec(["wordnet"], wordnet_dir=str(tiny_wordnet), params=params,
                                  cache_dir=tmp_path)
    assert info["cache_hit"] is False
    meta = json.loads((Path(info["path"]) / "meta.json").read_text())
    assert meta["sentences"] == 1600 and meta["words"] == len(first)
    again, info2 = cached_word2vec(["wordnet"], wordnet_dir=str(tiny_wordnet), params=params,
                                   cache_dir=tmp_path)
    assert info2["cache_hit"] is True and info2["path"] == info["path"]
    assert isinstance(again.kv.vectors, np.memmap)
    assert np.array_equal(np.asarray(again.kv.vectors), np.asarray(first.kv.vectors))
    _, info3 = cached_word2vec(["wordnet"], wordnet_dir=str(tiny_wordnet), cache_dir=tmp_path,
                               params=Word2VecParams(vector_size=16, epochs=3))
    assert info3["cache_hit"] is False and info3["path"] != info["path"]


def test_pretrained_files_load_memory_mapped_in_every_format(tmp_path):
    kv = hand_made_vectors()
    kv.save_word2vec_format(str(tmp_path / "vectors.txt"), binary=False)
    kv.save_word2vec_format(str(tmp_path / "vectors.bin"), binary=True)
    kv.save(str(tmp_path / "vectors.kv"), sep_limit=0)
    for name in ("vectors.txt", "vectors.bin", "vectors.kv"):
        loaded, info = load_pretrained(str(tmp_path / name), cache_dir=tmp_path / "cache")
        assert loaded.kv.index_to_key == kv.index_to_key, name
        assert np.allclose(np.asarray(loaded.kv.vectors), kv.vectors, atol=1e-6), name
        assert isinstance(loaded.kv.vectors, np.memmap), name
    _, again = load_pretrained(str(tmp_path / "vectors.bin"), cache_dir=tmp_path / "cache")
    assert again["cache_hit"] is True
    limited, _ = load_pretrained(str(tmp_path / "vectors.txt"), cache_dir=tmp_path / "cache",
                                 limit=5)
    assert len(limited) == 5


def test_bad_model_sources_are_clear_errors(tmp_path):
    with pytest.raises(ModelError, match="no word-vector file at"):
        load_pretrained(str(tmp_path / "missing.bin"))
    broken = tmp_path / "broken.txt"
    broken.write_text("this is not\na word2vec file\n")
    with pytest.raises(ModelError, match="cannot read .*broken.txt as word2vec text format"):
        load_pretrained(str(broken), cache_dir=tmp_path)
    with pytest.raises(ModelError, match="unknown embedding source 'glove'"):
        load_embeddings("glove")
    with pytest.raises(ModelError, match="needs pretrained_path"):
        load_embeddings("pretrained")
