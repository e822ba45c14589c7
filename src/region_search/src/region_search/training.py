"""Training word2vec reproducibly, caching it on disk, and loading pretrained vectors memory-mapped.

- `train_word2vec(sentences, params)`: gensim Word2Vec with one worker, a fixed seed and a
  deterministic `hashfxn` (crc32, not Python's salted `hash`), so two trainings give identical
  vectors whatever PYTHONHASHSEED is.
- `cached_word2vec(corpora, ...)`: trains once per (corpus contents, parameters, gensim version)
  and keeps the vectors in gensim's native format under the cache folder; later calls (and other
  processes) load them memory-mapped. Concurrent trainings are serialised with a file lock.
- `load_pretrained(path, ...)`: any KeyedVectors file: gensim native `.kv` (memory-mapped as it
  is) or word2vec binary/text (e.g. GoogleNews-vectors-negative300.bin[.gz], converted once into
  the cache, then memory-mapped).
- `load_embeddings(source, ...)`: the one entry point the nodes and benchmarks use.
"""
import fcntl
import hashlib
import json
import logging
import os
import shutil
import tempfile
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from region_search.corpora import DEFAULT_WORDNET_DIR, WordNet, brown_sentences, file_fingerprint, find_brown
from region_search.embeddings import WordEmbeddings
from region_search.errors import CorpusError, ModelError
from region_search.progress import LoadProgress

__all__ = ["Word2VecParams", "stable_hash", "train_word2vec", "default_cache_dir",
           "corpus_sentences", "cached_word2vec", "load_pretrained", "load_embeddings", "SOURCES"]

LOG = logging.getLogger(__name__)
CACHE_FORMAT = 1
SOURCES = ("auto", "brown", "wordnet", "brown+wordnet")


@dataclass(frozen=True)
class Word2VecParams:
    """gensim Word2Vec hyper-parameters (skip-gram by default: better on small corpora)."""

    vector_size: int = 100
    window: int = 5
    min_count: int = 2
    sg: int = 1
    negative: int = 5
    sample: float = 1e-3
    epochs: int = 15
    seed: int = 1


def stable_hash(text: str) -> int:
    """Deterministic replacement for Python's per-process salted `hash` (gensim's hashfxn)."""
    return zlib.crc32(text.encode("utf-8"))


def default_cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "robot_ws" / "embeddings"


def train_word2vec(sentences: Sequence[List[str]], params: Word2VecParams = Word2VecParams(),
                   *, progress: bool = False, monitor: Optional[LoadProgress] = None):
    """(KeyedVectors, counts) of a reproducible word2vec training (one worker, fixed seed).
    `progress`: a tqdm bar of the epochs; `monitor`: told of every finished epoch."""
    from gensim.models import Word2Vec
    from gensim.models.callbacks import CallbackAny2Vec

    sentences = list(sentences)
    if not sentences:
        raise CorpusError("no sentences to train on")
    callbacks = []
    if progress:
        from tqdm import tqdm

        class _Epochs(CallbackAny2Vec):
            def __init__(self):
                self.bar = tqdm(total=params.epochs, desc="word2vec epochs", unit="epoch")

            def on_epoch_end(self, model):
                self.bar.update(1)

            def on_train_end(self, model):
                self.bar.close()

        callbacks.append(_Epochs())
    if monitor is not None:

        class _Monitor(CallbackAny2Vec):
            def on_epoch_end(self, model):
                monitor.epoch_done()

        monitor.training_started(params.epochs, sum(len(s) for s in sentences))
        callbacks.append(_Monitor())
    model = Word2Vec(sentences, vector_size=params.vector_size, window=params.window,
                     min_count=params.min_count, sg=params.sg, negative=params.negative,
                     sample=params.sample, epochs=params.epochs, seed=params.seed, workers=1,
                     hashfxn=stable_hash, callbacks=callbacks)
    if monitor is not None:
        monitor.training_done()
    if len(model.wv) == 0:
        raise CorpusError(f"no word occurs min_count={params.min_count} times in the corpus")
    counts = np.array([model.wv.get_vecattr(w, "count") for w in model.wv.index_to_key],
                      dtype=np.int64)
    return model.wv, counts


def corpus_sentences(corpora: Sequence[str], *, brown_path: str = "",
                     wordnet_dir: str = DEFAULT_WORDNET_DIR) -> Tuple[List[List[str]], List[Path]]:
    """(sentences, files they came from) of the named corpora: "brown" and/or "wordnet"."""
    sentences: List[List[str]] = []
    files: List[Path] = []
    for name in corpora:
        if name == "brown":
            source = find_brown(brown_path)
            if source is None:
                raise CorpusError("no Brown corpus found (set brown_path or NLTK_DATA)")
            sentences += brown_sentences(source)
            files += [source] if source.is_file() else sorted(source.iterdir())
        elif name == "wordnet":
            wordnet = WordNet(wordnet_dir)
            sentences += wordnet.gloss_sentences()
            files += wordnet.data_files()
        else:
            raise CorpusError(f"unknown corpus {name!r}; use 'brown' or 'wordnet'")
    return sentences, [f for f in files if f.is_file()]


def cached_word2vec(corpora: Sequence[str], *, brown_path: str = "",
                    wordnet_dir: str = DEFAULT_WORDNET_DIR,
                    params: Word2VecParams = Word2VecParams(), cache_dir: Optional[Path] = None,
                    progress: bool = False, options: Optional[Dict] = None,
                    monitor: Optional[LoadProgress] = None) -> Tuple[WordEmbeddings, Dict]:
    """Word2vec on the corpora, trained once and then loaded (memory-mapped) from the cache.

    Returns (embeddings, info) with info keys: cache_hit, seconds, path, corpora, params (and
    train_seconds when it trained). `monitor` (optional) follows the stages and epochs.
    """
    import gensim

    start = time.monotonic()
    cache_dir = Path(cache_dir or default_cache_dir())
    fingerprints = _corpus_fingerprints(corpora, brown_path, wordnet_dir)
    key = hashlib.sha256(json.dumps({"corpora": fingerprints, "params": asdict(params),
                                     "gensim": gensim.__version__, "format": CACHE_FORMAT},
                                    sort_keys=True).encode()).hexdigest()[:20]
    folder = cache_dir / f"word2vec-{'+'.join(corpora)}-{key}"
    info = {"corpora": list(corpora), "params": asdict(params), "path": str(folder)}
    if not (folder / "meta.json").is_file():
        cache_dir.mkdir(parents=True, exist_ok=True)
        with open(cache_dir / f".{folder.name}.lock", "w") as lock:
            if monitor is not None:
                monitor.set_stage("waiting for another process training the same model")
            fcntl.flock(lock, fcntl.LOCK_EX)  # another process may be training the same model
            if not (folder / "meta.json").is_file():
                info["train_seconds"] = _train_into(folder, corpora, brown_path, wordnet_dir,
                                                    params, progress, monitor)
                info["cache_hit"] = False
    info.setdefault("cache_hit", True)
    if monitor is not None:
        monitor.set_stage("loading the cached vectors")
    embeddings = _load_folder(folder, wordnet_dir, options)
    info["seconds"] = time.monotonic() - start
    return embeddings, info


def _corpus_fingerprints(corpora, brown_path, wordnet_dir) -> Dict[str, str]:
    prints = {}
    for name in corpora:
        if name == "brown":
            source = find_brown(brown_path)
            if source is None:
                raise CorpusError("no Brown corpus found (set brown_path or NLTK_DATA)")
            files = [source] if source.is_file() else sorted(source.iterdir())
        elif name == "wordnet":
            files = WordNet(wordnet_dir).data_files()
        else:
            raise CorpusError(f"unknown corpus {name!r}; use 'brown' or 'wordnet'")
        prints[name] = file_fingerprint([f for f in files if f.is_file()])
    return prints


def _train_into(folder: Path, corpora, brown_path, wordnet_dir, params, progress,
                monitor: Optional[LoadProgress] = None) -> float:
    """Train into `folder` (atomically); the seconds it took, corpus reading included."""
    start = time.monotonic()
    if monitor is not None:
        monitor.set_stage("reading the corpus")
    sentences, _ = corpus_sentences(corpora, brown_path=brown_path, wordnet_dir=wordnet_dir)
    tokens = sum(len(s) for s in sentences)
    LOG.info("training word2vec on %s (%d sentences, %d tokens, %d epochs; this is done once, "
             "then the model is loaded from %s)", "+".join(corpora), len(sentences), tokens,
             params.epochs, folder.parent)
    kv, counts = train_word2vec(sentences, params, progress=progress, monitor=monitor)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        kv.save(str(tmp / "vectors.kv"), sep_limit=0)  # arrays in .npy files: memory-mappable
        np.save(tmp / "counts.npy", counts)
        meta = {"corpora": list(corpora), "params": asdict(params), "words": len(kv),
                "tokens": int(sum(len(s) for s in sentences)), "sentences": len(sentences),
                "train_seconds": time.monotonic() - start, "counts": True}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
        os.replace(tmp, folder)  # atomic: a folder with meta.json is always complete
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return meta["train_seconds"]


def _load_folder(folder: Path, wordnet_dir: str = DEFAULT_WORDNET_DIR,
                 options: Optional[Dict] = None) -> WordEmbeddings:
    from gensim.models import KeyedVectors

    meta = json.loads((folder / "meta.json").read_text())
    try:
        kv = KeyedVectors.load(str(folder / "vectors.kv"), mmap="r")
    except (OSError, ValueError, EOFError) as err:
        raise ModelError(f"cannot load cached vectors {folder}: {err}") from err
    counts = np.load(folder / "counts.npy") if meta.get("counts") else None
    description = meta.get("description") or (
        f"word2vec on {'+'.join(meta.get('corpora', []))}: {len(kv)} words x {kv.vector_size}")
    return WordEmbeddings(kv, counts=counts, base_forms=_wordnet_base_forms(wordnet_dir),
                          description=description, **(options or {}))


def load_pretrained(path: str, *, cache_dir: Optional[Path] = None, binary: Optional[bool] = None,
                    limit: Optional[int] = None, wordnet_dir: str = DEFAULT_WORDNET_DIR,
                    options: Optional[Dict] = None) -> Tuple[WordEmbeddings, Dict]:
    """Pretrained KeyedVectors: native .kv memory-mapped directly; word2vec binary/text files
    (binary when the name has .bin, unless `binary` says otherwise) are converted once into the
    cache and then memory-mapped. `limit` keeps only the first (most frequent) words.
    """
    from gensim.models import KeyedVectors

    start = time.monotonic()
    source = Path(path).expanduser()
    if not source.is_file():
        raise ModelError(f"no word-vector file at {path!r}")
    info: Dict = {"path": str(source), "cache_hit": True}
    if source.suffix == ".kv":
        try:
            kv = KeyedVectors.load(str(source), mmap="r")
        except Exception as err:  # noqa: BLE001 - gensim raises many kinds here
            raise ModelError(f"cannot load {source} as gensim KeyedVectors: {err}") from err
        counts = kv.expandos.get("count") if hasattr(kv, "expandos") else None
        if counts is not None and np.asarray(counts).sum() <= 0:
            counts = None
        embeddings = WordEmbeddings(kv, counts=counts, base_forms=_wordnet_base_forms(wordnet_dir),
                                    description=f"pretrained {source.name}: {len(kv)} words",
                                    **(options or {}))
        info["seconds"] = time.monotonic() - start
        return embeddings, info
    stat = source.stat()
    key = hashlib.sha256(f"{source.resolve()}:{stat.st_size}:{stat.st_mtime_ns}:{limit}:"
                         f"{binary}:{CACHE_FORMAT}".encode()).hexdigest()[:20]
    cache_dir = Path(cache_dir or default_cache_dir())
    folder = cache_dir / f"pretrained-{source.name}-{key}"
    if not (folder / "meta.json").is_file():
        is_binary = ".bin" in source.name if binary is None else binary
        cache_dir.mkdir(parents=True, exist_ok=True)
        with open(cache_dir / f".{folder.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (folder / "meta.json").is_file():
                _convert_into(folder, source, is_binary, limit)
                info["cache_hit"] = False
    embeddings = _load_folder(folder, wordnet_dir, options)
    info["seconds"] = time.monotonic() - start
    info["cache"] = str(folder)
    return embeddings, info


def _convert_into(folder: Path, source: Path, binary: bool, limit: Optional[int]) -> None:
    from gensim.models import KeyedVectors

    try:
        kv = KeyedVectors.load_word2vec_format(str(source), binary=binary, limit=limit,
                                               unicode_errors="ignore")
    except Exception as err:  # noqa: BLE001 - gensim raises many kinds for a bad file
        kind = "binary" if binary else "text"
        raise ModelError(f"cannot read {source} as word2vec {kind} format: {err}") from err
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        kv.save(str(tmp / "vectors.kv"), sep_limit=0)
        meta = {"source": str(source), "words": len(kv), "counts": False,
                "description": f"pretrained {source.name}: {len(kv)} words x {kv.vector_size}"}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
        os.replace(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _wordnet_base_forms(wordnet_dir: str):
    """WordNet's morphy (noun, then verb, then adjective forms) when WordNet is installed."""
    try:
        wordnet = WordNet(wordnet_dir)
    except CorpusError:
        return None
    if not all((Path(wordnet_dir) / f"index.{n}").is_file() for n in ("noun", "verb", "adj")):
        return None

    def base_forms(word: str) -> List[str]:
        return [form for pos in ("n", "v", "a") for form in wordnet.morphy(word, pos)]

    return base_forms


def load_embeddings(source: str = "auto", *, pretrained_path: str = "", brown_path: str = "",
                    wordnet_dir: str = DEFAULT_WORDNET_DIR, params: Word2VecParams = Word2VecParams(),
                    cache_dir: Optional[Path] = None, progress: bool = False,
                    limit: Optional[int] = None, options: Optional[Dict] = None,
                    monitor: Optional[LoadProgress] = None) -> Tuple[WordEmbeddings, Dict]:
    """The embedding model a node serves.

    source: "auto" (Brown + WordNet glosses when a Brown corpus is found, else WordNet glosses),
    "brown", "wordnet", "brown+wordnet", or "pretrained" (then `pretrained_path` is required).
    options: keyword arguments of WordEmbeddings (e.g. remove_components).
    monitor: follows the stages and training epochs (the embedding server reports it).
    """
    if source == "pretrained":
        if not pretrained_path:
            raise ModelError("source 'pretrained' needs pretrained_path")
        if monitor is not None:
            monitor.set_stage("loading pretrained vectors")
        return load_pretrained(pretrained_path, cache_dir=cache_dir, limit=limit,
                               wordnet_dir=wordnet_dir, options=options)
    if source not in SOURCES:
        raise ModelError(f"unknown embedding source {source!r}; use one of "
                         f"{SOURCES + ('pretrained',)}")
    if source == "auto":
        corpora: Iterable[str] = ("brown", "wordnet") if find_brown(brown_path) else ("wordnet",)
    else:
        corpora = source.split("+")
    return cached_word2vec(list(corpora), brown_path=brown_path, wordnet_dir=wordnet_dir,
                           params=params, cache_dir=cache_dir, progress=progress,
                           options=options, monitor=monitor)
