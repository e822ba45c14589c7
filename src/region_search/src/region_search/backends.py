"""The embedding backends a server can serve, chosen by name, with a fallback that says so.

- "sentence" (default): a pretrained sentence model (region_search.sentence; all-MiniLM-L6-v2 unless
  `model_path` names another local sentence-transformers folder): whole-phrase vectors.
- "static": pretrained static token vectors averaged per phrase (region_search.static_vectors;
  the `wordllama` package's weights, NumPy and `tokenizers` only: no PyTorch, nothing trained).
- "word2vec": word vectors (region_search.embeddings.WordEmbeddings): trained on Brown + WordNet glosses and
  cached (`source`), or any pretrained KeyedVectors file (`model_path`, or `source` "pretrained"
  with `pretrained_path`).

When the sentence model cannot be loaded (PyTorch or sentence-transformers missing, as on a
Python 3.8 robot; a folder without a model), `load_backend` serves the static vectors instead,
or word2vec when they are missing too (unless `fallback` is off), and returns why in
`LoadedBackend.note`, which the server logs and puts in every response.
"""
import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Union

from region_search.embeddings import WordEmbeddings
from region_search.errors import ModelError
from region_search.params import BACKENDS, EmbeddingServerParams
from region_search.progress import LoadProgress
from region_search.sentence import SentenceEmbeddings, load_sentence_model
from region_search.static_vectors import load_static_model
from region_search.training import load_embeddings

__all__ = ["BACKENDS", "EmbeddingServerParams", "LoadedBackend", "load_backend"]

LOG = logging.getLogger(__name__)
Embeddings = Union[SentenceEmbeddings, WordEmbeddings]


@dataclass
class LoadedBackend:
    """A loaded model: `backend` is the one actually served; `note` is "" or the fallback reason."""

    embeddings: Embeddings
    backend: str
    note: str
    load_seconds: float
    info: Dict = field(default_factory=dict)


def load_backend(config: Optional[EmbeddingServerParams] = None, *, progress: bool = False,
                 monitor: Optional[LoadProgress] = None) -> LoadedBackend:
    """The model to serve (default: EmbeddingServerParams()); ModelError when it (and its allowed
    fallback) cannot be loaded. `progress`: tqdm bars; `monitor`: follows the loading stages
    and the word2vec training epochs (the caller marks it finished)."""
    config = config if config is not None else EmbeddingServerParams()
    if config.backend not in BACKENDS:
        raise ModelError(f"unknown embedding backend {config.backend!r}; use one of {BACKENDS}")
    start = time.monotonic()
    failures = []  # (backend, reason) of the backends tried before the one served
    for backend in BACKENDS[BACKENDS.index(config.backend):]:
        if monitor is not None and backend != "word2vec":
            monitor.set_stage(f"loading the {backend} model")
        try:
            if backend == "sentence":
                embeddings = load_sentence_model(config.model_path, threads=config.threads,
                                                 cache_size=config.cache_size,
                                                 batch_size=config.batch_size)
            elif backend == "static":
                embeddings = load_static_model(cache_size=config.cache_size,
                                               batch_size=config.batch_size)
            else:
                break
        except ModelError as err:
            if not config.fallback:
                raise ModelError(f"{backend} model unavailable (fallback disabled): {err}") \
                    from err
            failures.append(f"{backend} model unavailable: {err}")
            continue
        note = _fallback_note(backend, failures)
        return LoadedBackend(embeddings, backend, note, time.monotonic() - start)
    note = _fallback_note("word2vec", failures)
    embeddings, info = _load_word2vec(config, use_model_path=config.backend == "word2vec",
                                      progress=progress, monitor=monitor)
    return LoadedBackend(embeddings, "word2vec", note, time.monotonic() - start, info)


def _fallback_note(backend: str, failures: List[str]) -> str:
    """"" when the backend asked for is served, else why another one is (logged once)."""
    if not failures:
        return ""
    note = f"fallback to {backend}: " + "; ".join(failures)
    LOG.warning("%s", note)
    return note


def _word2vec_source(config: EmbeddingServerParams, use_model_path: bool) -> str:
    return "pretrained" if use_model_path and config.model_path else config.source


def _load_word2vec(config: EmbeddingServerParams, *, use_model_path: bool, progress: bool,
                   monitor: Optional[LoadProgress] = None):
    source = _word2vec_source(config, use_model_path)
    path = config.model_path if use_model_path and config.model_path else config.pretrained_path
    cache_dir: Optional[str] = config.cache_dir or None
    return load_embeddings(source, pretrained_path=path, brown_path=config.brown_path,
                           wordnet_dir=config.wordnet_dir, params=config.word2vec,
                           cache_dir=cache_dir, progress=progress, limit=config.limit or None,
                           options={"remove_components": config.remove_components},
                           monitor=monitor)
