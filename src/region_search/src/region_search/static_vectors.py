"""Phrase vectors without PyTorch: pretrained static token vectors, averaged over a phrase.

The vectors are WordLlama's `l2_supercat` 256-d token embeddings (MIT licence; trained from large
language models' token embeddings for sentence similarity), as the pip package `wordllama`
ships them: a 16 MB safetensors file and a tokenizers file inside the wheel. They are read here
with NumPy and the `tokenizers` library only (the `wordllama` package itself is not imported),
after checking the weights' SHA-256, so nothing is downloaded and nothing is trained at first
start: a fresh process has its first vector in well under a second. A phrase's vector is the
mean of its tokens' vectors, unit length (as WordLlama's own `embed`).

`load_static_model()` returns a `sentence.SentenceEmbeddings` (the same interface, cache and
notes as the sentence model) whose backend is "static".
"""
import hashlib
import json
import struct
from importlib.util import find_spec
from pathlib import Path
from typing import Dict, List, Sequence

import numpy as np

from region_search.errors import ModelError
from region_search.sentence import SentenceEmbeddings

__all__ = ["STATIC_PACKAGE", "STATIC_SHA256", "StaticPhraseModel", "load_static_model"]

STATIC_PACKAGE = "wordllama"
WEIGHTS = "weights/l2_supercat_256.safetensors"
TOKENIZER = "tokenizers/l2_supercat_tokenizer_config.json"
STATIC_SHA256 = "64b47a2dc493cb8e85944076601189739852d7b64e0e1eedcb1937a251cd9fd5"
WORD_START = "\u2581"  # SentencePiece's mark of a token that starts a word


def package_dir() -> Path:
    """The installed wordllama package's folder (not imported); ModelError when missing."""
    try:
        spec = find_spec(STATIC_PACKAGE)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise ModelError("the static phrase vectors are not installed (pip package wordllama)")
    return Path(list(spec.submodule_search_locations)[0])


def read_safetensors(path: Path, key: str = "embedding.weight",
                     sha256: str = STATIC_SHA256) -> np.ndarray:
    """One tensor of a safetensors file (8-byte header length, JSON header, raw data), after
    checking the file's SHA-256 ("" = unchecked); ModelError when anything is wrong."""
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ModelError(f"cannot read the static vectors {path}: {err.strerror}") from err
    if sha256 and hashlib.sha256(raw).hexdigest() != sha256:
        raise ModelError(f"{path} is not the expected weights file (SHA-256 differs)")
    try:
        (size,) = struct.unpack("<Q", raw[:8])
        entry = json.loads(raw[8:8 + size])[key]
        dtype = {"F32": np.float32, "F16": np.float16}[entry["dtype"]]
        start, end = entry["data_offsets"]
        data = np.frombuffer(raw[8 + size + start:8 + size + end], dtype=dtype)
        return data.reshape(entry["shape"]).astype(np.float32)
    except (struct.error, ValueError, KeyError, TypeError) as err:
        raise ModelError(f"{path} is not a safetensors file with {key!r}: {err!r}") from err


class _Tokenizer:
    """The two tokenizer calls SentenceEmbeddings makes (vocabulary words, a word's pieces)."""

    def __init__(self, tokenizer):
        self.tokenizer = tokenizer

    def get_vocab(self) -> Dict[str, int]:
        return {token[len(WORD_START):]: index
                for token, index in self.tokenizer.get_vocab().items()
                if token.startswith(WORD_START)}

    def tokenize(self, text: str) -> List[str]:
        return [t.replace(WORD_START, "") or WORD_START
                for t in self.tokenizer.encode(text, add_special_tokens=False).tokens]


class StaticPhraseModel:
    """`encode` as a sentence-transformers model has it: the mean of each text's token vectors."""

    def __init__(self, table: np.ndarray, tokenizer):
        self.table = table
        self.raw_tokenizer = tokenizer
        self.tokenizer = _Tokenizer(tokenizer)

    def get_sentence_embedding_dimension(self) -> int:
        return int(self.table.shape[1])

    def encode(self, texts: Sequence[str], normalize_embeddings: bool = True,
               **_options) -> np.ndarray:
        vectors = np.zeros((len(texts), self.table.shape[1]), dtype=np.float32)
        encoded = self.raw_tokenizer.encode_batch(list(texts), add_special_tokens=False)
        for row, encoding in enumerate(encoded):
            ids = np.clip(np.asarray(encoding.ids, dtype=np.int64), 0, len(self.table) - 1)
            if len(ids):
                vectors[row] = self.table[ids].mean(axis=0)
        if normalize_embeddings:
            vectors /= np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-12)
        return vectors


def load_static_model(*, cache_size: int = 10_000, batch_size: int = 64) -> SentenceEmbeddings:
    """The static phrase vectors as embeddings with the sentence model's interface; ModelError
    when the package, its files or the `tokenizers` library are missing or wrong."""
    folder = package_dir()
    table = read_safetensors(folder / WEIGHTS)
    try:
        from tokenizers import Tokenizer

        tokenizer = Tokenizer.from_file(str(folder / TOKENIZER))
    except ImportError as err:
        raise ModelError(f"cannot import the tokenizers library: {err}") from err
    except Exception as err:  # noqa: BLE001 - the Rust library raises its own exception type
        raise ModelError(f"cannot read the tokenizer {folder / TOKENIZER}: {err}") from err
    tokenizer.no_padding()
    tokenizer.no_truncation()
    embeddings = SentenceEmbeddings(StaticPhraseModel(table, tokenizer),
                                    cache_size=cache_size, batch_size=batch_size)
    embeddings.backend = "static"
    embeddings.description = (f"static phrase vectors (WordLlama l2_supercat, {len(table)} "
                              f"tokens): {embeddings.dimension}-d, mean of token vectors")
    return embeddings
