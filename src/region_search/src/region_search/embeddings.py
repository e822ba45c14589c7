"""Word vectors for phrases and label names, with fallbacks for words a model lacks.

`WordEmbeddings` wraps a gensim `KeyedVectors` (trained here or pretrained, possibly
memory-mapped) and answers:
- `word_vector(word)`: a unit vector and a note saying how it was found: the word itself; a base
  form ("restrooms" -> "restroom"); sub-words ("mailroom" -> "mail" + "room"); the vocabulary
  word spelled most alike ("towne" -> "town"); or nothing (numbers never get a vector: room 321
  is matched by spelling only).
- `embed_words` / `embed_phrase`: phrase vectors as SIF-weighted means (Arora et al. 2017: weight
  a / (a + p(word)), so frequent words count less) of unit word vectors.
- `similarity(phrase, candidates, method)`: one phrase against many candidates, by cosine of the
  phrase vectors ("mean") or by each phrase word's best-matching candidate word ("align").
Every result lists the words without a vector of their own (`oov`) and the fallbacks used.
"""
import logging
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from region_search.errors import EmbeddingError, EmptyPhraseError
from region_search.text_similarity import SpellingIndex, content_words, is_number, tokenize

__all__ = ["EmbeddedWords", "WordEmbeddings", "METHODS", "phrase_tokens"]

LOG = logging.getLogger(__name__)
METHODS = ("mean", "align")


@dataclass
class EmbeddedWords:
    """Vectors of a list of words (or phrases): row i belongs to `words[i]`.

    `vectors` rows are unit length, or zero where nothing could be embedded; `weights` are the
    SIF weights (1 for words the model does not know); `notes[i]` is "" when the word itself was
    in the vocabulary, otherwise it says which fallback was used.
    """

    words: List[str]
    vectors: np.ndarray
    weights: np.ndarray
    notes: List[str] = field(default_factory=list)
    oov: List[str] = field(default_factory=list)

    @property
    def found(self) -> np.ndarray:
        return np.any(self.vectors != 0.0, axis=1)


def phrase_tokens(phrase: str) -> List[str]:
    """The content words of a phrase; EmptyPhraseError when it has no words at all."""
    if not isinstance(phrase, str):
        raise EmptyPhraseError(f"a phrase must be a string, got {type(phrase).__name__}")
    tokens = tokenize(phrase)
    if not tokens:
        raise EmptyPhraseError(f"the phrase {phrase!r} has no words")
    return content_words(tokens)


class WordEmbeddings:
    """Phrase and word vectors from gensim KeyedVectors, with out-of-vocabulary fallbacks.

    Args:
        keyed_vectors: gensim KeyedVectors (memory-mapped ones are fine; they are only read).
        counts: corpus count of each vocabulary word (in index order); None for pretrained
            vectors, whose word probabilities are then estimated from the frequency rank (Zipf).
        base_forms: word -> candidate base forms (e.g. WordNet's morphy); default: plural rules.
        sif_a: the SIF smoothing constant a.
        remove_components: post-processing of the vectors ("all-but-the-top", Mu and Viswanath
            2018): -1 none; 0 subtract the mean vector; k > 0 also remove the top k principal
            components. Word2vec vectors share a common direction (unrelated words have cosines
            near 0.6 on a small corpus); removing it makes cosines meaningful.
        spelling_vocabulary: how many of the most frequent words the spelling fallback searches.
        min_spelling_similarity: below this trigram similarity the spelling fallback gives up.
        description: what the vectors are (shown by the service).
    """

    backend = "word2vec"
    phrase_level = False  # phrase vectors are means of word vectors: match word by word

    def __init__(self, keyed_vectors, *, counts: Optional[np.ndarray] = None,
                 base_forms: Optional[Callable[[str], List[str]]] = None, sif_a: float = 1e-3,
                 remove_components: int = 1, postprocess_sample: int = 50_000,
                 spelling_vocabulary: int = 100_000, min_spelling_similarity: float = 0.6,
                 description: str = ""):
        if len(keyed_vectors) == 0:
            raise EmbeddingError("the word-vector model has no words")
        self.kv = keyed_vectors
        self.dimension = int(keyed_vectors.vector_size)
        self.description = description
        self.base_forms = base_forms or _plural_base_forms
        self.sif_a = sif_a
        self.spelling_vocabulary = spelling_vocabulary
        self.min_spelling_similarity = min_spelling_similarity
        self.probabilities = _word_probabilities(len(keyed_vectors), counts)
        self._spelling: Optional[SpellingIndex] = None
        self.mean_, self.components_ = _common_directions(keyed_vectors, remove_components,
                                                          postprocess_sample)

    def __len__(self) -> int:
        return len(self.kv)

    def warm_up(self) -> None:
        """Build the spelling index now, not on the first request that needs it."""
        self.spelling_index()

    def __contains__(self, word: str) -> bool:
        return word in self.kv.key_to_index

    # -- words -------------------------------------------------------------------------------
    def weight(self, word: str) -> float:
        """SIF weight a / (a + p(word)); 1 for a word outside the vocabulary."""
        index = self.kv.key_to_index.get(word)
        if index is None:
            return 1.0
        return float(self.sif_a / (self.sif_a + self.probabilities[index]))

    def _unit(self, word: str) -> np.ndarray:
        vector = np.asarray(self.kv[word], dtype=np.float64) - self.mean_
        if len(self.components_):
            vector = vector - self.components_.T @ (self.components_ @ vector)
        norm = np.linalg.norm(vector)
        return vector / norm if norm > 0 else vector

    def word_vector(self, word: str) -> Tuple[Optional[np.ndarray], str, float]:
        """(unit vector or None, note, SIF weight) of one word; the note is "" when in vocabulary."""
        if word in self.kv.key_to_index and not is_number(word):
            return self._unit(word), "", self.weight(word)
        if is_number(word):
            return None, f"{word}: a number, matched by spelling only", 1.0
        for base in self.base_forms(word):
            if base != word and base in self.kv.key_to_index:
                return self._unit(base), f"{word}: not in vocabulary, used base form '{base}'", \
                    self.weight(base)
        parts = self._split_compound(word)
        if parts:
            vector = self._unit(parts[0]) + self._unit(parts[1])
            weight = max(self.weight(parts[0]), self.weight(parts[1]))
            return vector / np.linalg.norm(vector), \
                f"{word}: not in vocabulary, used sub-words '{parts[0]}' + '{parts[1]}'", weight
        match = self.spelling_index().nearest(word)
        if match is not None:
            return self._unit(match[0]), (f"{word}: not in vocabulary, used the word spelled most "
                                          f"alike '{match[0]}' ({match[1]:.2f})"), 1.0
        return None, f"{word}: not in vocabulary, no sub-words or similar spelling: no vector", 1.0

    def _split_compound(self, word: str) -> Optional[Tuple[str, str]]:
        """Two vocabulary words that make up `word` ("mailroom" -> "mail", "room"), if any."""
        best = None
        for cut in range(3, len(word) - 2):
            left, right = word[:cut], word[cut:]
            if left in self.kv.key_to_index and right in self.kv.key_to_index:
                balance = min(len(left), len(right))
                if best is None or balance > best[0]:
                    best = (balance, left, right)
        return (best[1], best[2]) if best else None

    def spelling_index(self) -> SpellingIndex:
        if self._spelling is None:
            words = self.kv.index_to_key[:self.spelling_vocabulary]
            self._spelling = SpellingIndex(words, min_similarity=self.min_spelling_similarity)
        return self._spelling

    def embed_words(self, words: Sequence[str]) -> EmbeddedWords:
        """Each word's unit vector (zero row when none), SIF weight and fallback note."""
        vectors = np.zeros((len(words), self.dimension))
        weights = np.ones(len(words))
        notes, oov = [], []
        for row, word in enumerate(words):
            vector, note, weight = self.word_vector(word)
            if vector is not None:
                vectors[row] = vector
            weights[row] = weight
            notes.append(note)
            if note:
                oov.append(word)
        return EmbeddedWords(list(words), vectors, weights, notes, oov)

    # -- phrases -----------------------------------------------------------------------------
    def embed_phrase(self, phrase: str) -> Tuple[np.ndarray, float, EmbeddedWords]:
        """(unit phrase vector or zeros, mean weight, its words) for a phrase of any length."""
        words = self.embed_words(phrase_tokens(phrase))
        return _weighted_mean(words), float(np.mean(words.weights)), words

    def embed_phrases(self, phrases: Sequence[str]) -> EmbeddedWords:
        """Phrase vectors as rows (EmbeddedWords with one row per phrase; notes joined)."""
        if not phrases:
            raise EmptyPhraseError("no phrases given")
        rows, weights, notes, oov = [], [], [], []
        for index, phrase in enumerate(phrases):
            try:
                vector, weight, words = self.embed_phrase(phrase)
            except EmptyPhraseError as err:
                raise EmptyPhraseError(f"phrase {index}: {err}") from None
            rows.append(vector)
            weights.append(weight)
            notes.append("; ".join(n for n in words.notes if n))
            oov += [w for w in words.oov if w not in oov]
        return EmbeddedWords(list(phrases), np.array(rows), np.array(weights), notes, oov)

    def similarity(self, phrase: str, candidates: Sequence[str],
                   method: str = "mean") -> Tuple[np.ndarray, EmbeddedWords]:
        """Scores in [-1, 1] of `phrase` against each candidate, and the phrase's words.

        method "mean": cosine of the SIF-weighted mean vectors; "align": for each phrase word
        the best cosine with any candidate word, averaged with the SIF weights.
        """
        if method not in METHODS:
            raise EmbeddingError(f"unknown similarity method {method!r}; use one of {METHODS}")
        if not candidates:
            raise EmptyPhraseError("no candidates given")
        query = self.embed_words(phrase_tokens(phrase))
        scores = np.zeros(len(candidates))
        for index, candidate in enumerate(candidates):
            try:
                words = self.embed_words(phrase_tokens(candidate))
            except EmptyPhraseError as err:
                raise EmptyPhraseError(f"candidate {index}: {err}") from None
            if method == "mean":
                scores[index] = float(_weighted_mean(query) @ _weighted_mean(words))
            else:
                scores[index] = align_score(query, words.vectors)
        return scores, query


def align_score(query: EmbeddedWords, target_vectors: np.ndarray,
                target_weights: Optional[np.ndarray] = None) -> float:
    """SIF-weighted mean over query words (with vectors) of their best (weighted) cosine."""
    found = query.found
    if not found.any() or len(target_vectors) == 0:
        return 0.0
    cosines = query.vectors[found] @ np.asarray(target_vectors).T
    if target_weights is not None:
        cosines = cosines * np.asarray(target_weights)[None, :]
    weights = query.weights[found]
    return float(np.sum(weights * cosines.max(axis=1)) / np.sum(weights))


def _common_directions(kv, remove_components: int, sample: int) -> Tuple[np.ndarray, np.ndarray]:
    """(mean vector, top principal directions) of the most frequent words' vectors."""
    dimension = int(kv.vector_size)
    if remove_components < 0:
        return np.zeros(dimension), np.zeros((0, dimension))
    vectors = np.asarray(kv.vectors[:sample], dtype=np.float64)
    mean = vectors.mean(axis=0)
    if remove_components == 0:
        return mean, np.zeros((0, dimension))
    _, _, directions = np.linalg.svd(vectors - mean, full_matrices=False)
    return mean, directions[:remove_components]


def _weighted_mean(words: EmbeddedWords) -> np.ndarray:
    total = (words.weights[:, None] * words.vectors).sum(axis=0)
    norm = np.linalg.norm(total)
    return total / norm if norm > 0 else total


def _word_probabilities(size: int, counts: Optional[np.ndarray]) -> np.ndarray:
    if counts is not None:
        counts = np.asarray(counts, dtype=np.float64)
        if counts.shape != (size,) or counts.sum() <= 0:
            raise EmbeddingError(f"counts must be {size} non-negative numbers with a positive sum")
        return counts / counts.sum()
    # Zipf's law for a vocabulary sorted by frequency: p(rank r) = 1 / (r * H_size).
    ranks = np.arange(1, size + 1, dtype=np.float64)
    return 1.0 / (ranks * (np.log(size) + 0.5772))


def _plural_base_forms(word: str) -> List[str]:
    forms = []
    if word.endswith("ies") and len(word) > 4:
        forms.append(word[:-3] + "y")
    if word.endswith("es") and len(word) > 3:
        forms.append(word[:-2])
    if word.endswith("s") and not word.endswith("ss") and len(word) > 3:
        forms.append(word[:-1])
    return forms
