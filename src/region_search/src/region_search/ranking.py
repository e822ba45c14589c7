"""Ranking labelled places for a phrase from several kinds of evidence, with "no place matches".

Each label gets one row of evidence (`FEATURES`) for a phrase:

- `name`: similarity of the phrase with the label's name ("printer room");
- `knowledge`: with what WordNet says the kind of place is for (knowledge.PlaceKnowledge.text:
  "printer room: an output device that prints ...");
- `expanded`: with the name and its WordNet words (synonyms, related words, definitions);
- `compounds`: the best similarity with one of WordNet's compound nouns that contain a word of
  the label, with its definition ("coffee break: a short break from work for refreshments"),
  among the `compound_keep` closest to the label's own knowledge text (its sense of the word);
- `spelling`: how much of the phrase spells the label's name, each name word weighted by how
  specific it is in this label set (a word every label has, such as "room", counts little);
- `number_match` / `number_mismatch`: the phrase names a number the label carries / the label
  carries only other numbers (room 321 is not room 312);
- `query_words` (word2vec only; 0 with the sentence backend): as `expanded`, with the phrase's
  words expanded by their own WordNet words too ("launder my shirts": launder -> laundry).

The similarities come from the embedding backend: phrase vectors of the sentence model
(`SentenceFeatures`), or word vectors with the word-by-word method (`WordFeatures`). A label's
score is the weighted sum of its row (`RankingWeights`, chosen by leave-one-building-out in
bench/region_search/nlp_region_accuracy.py and shipped in region_search/ranking_weights.yaml).

Descriptions (what a visitor's sign says) never replace a label's own evidence: a described
label is also scored as if the description were its name, less `description_offset`, and keeps
the better of the two. So a description adds evidence for its own place only, and only when the
phrase matches it better than the label's own name and knowledge do; it cannot lower any
label's score. When the best score's lead over the mean score is below `no_match_margin`, no
labelled place matches. The answer's confidence (how likely the first place is the one meant) is
a logistic function of that lead and of the gap to the second place (`RankingWeights.confidence`,
fitted by the same bench); below `sure_confidence` the ranking is given as a best guess.

Label sets are replaced atomically: `set_regions` computes everything for the new labels (the
embedding backend may fail or still be loading half-way) and only then publishes it; a failed
call leaves the previous labels in use, and the next call goes on where it stopped.
"""
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords, phrase_tokens
from region_search.errors import EmbeddingError
from region_search.knowledge import PlaceKnowledge
from region_search.labels import (
    RankedRegion,
    Recommendation,
    Region,
    descriptions_of,
    distinct_places,
)
from region_search.ranking_settings import (
    DEFAULT_WEIGHTS_PATH,
    FEATURES,
    RankingWeights,
    lead_and_gap,
    load_ranking_weights,
)
from region_search.text_similarity import (
    STOPWORDS,
    content_words,
    is_number,
    spelling_similarity,
    spoken_numbers,
    tokenize,
)
from region_search.word_matching import ExpansionWeights, LabelExpander, WordMatcher

__all__ = ["FEATURES", "RankingWeights", "load_ranking_weights", "DEFAULT_WEIGHTS_PATH",
           "QueryEvidence", "SentenceFeatures", "WordFeatures", "PlaceRecommender",
           "specific_spelling", "lead_and_gap"]

Embed = Callable[[List[str]], EmbeddedWords]
# Label texts per embedding call when a label set is encoded (SentenceFeatures).
ENCODE_CHUNK = 1024


def specific_spelling(words: Sequence[str], name_words: Sequence[str],
                      specificity: Dict[str, float], min_similarity: float = 0.6) -> float:
    """Mean over the phrase's words of the best spelling match with a name word, times that
    name word's specificity in the label set (1: only this label has it); numbers excluded."""
    names = [w for w in name_words if w not in STOPWORDS and not is_number(w)]
    words = [w for w in words if not is_number(w)]
    if not words or not names:
        return 0.0
    total = 0.0
    for word in words:
        best, token = max((spelling_similarity(word, name), name) for name in names)
        if best >= min_similarity:
            total += best * specificity.get(token, 1.0)
    return total / len(words)


def _specificity(label_words: Dict[str, List[str]]) -> Dict[str, float]:
    """Per name word: log((n + 1) / labels having it) / log(n + 1) over the n labels."""
    counts: Dict[str, int] = {}
    for words in label_words.values():
        for word in set(words):
            counts[word] = counts.get(word, 0) + 1
    total = len(label_words)
    return {w: float(np.log((total + 1) / c) / np.log(total + 1)) for w, c in counts.items()}


def _numbers(text: str) -> set:
    return {t for t in tokenize(text) if is_number(t)}


@dataclass
class QueryEvidence:
    """A phrase's evidence for each label (rows in `names` order); `described` has the rows
    with each description taken as its label's name (None when no label has one)."""

    names: List[str]
    own: np.ndarray
    described: Optional[np.ndarray]
    oov: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)


@dataclass(frozen=True)
class _Labels:
    """One label set: sorted names, {name: description}, how specific each name word is."""

    names: Tuple[str, ...] = ()
    described: Dict[str, str] = field(default_factory=dict)
    specificity: Dict[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, regions: Sequence[Region]) -> "_Labels":
        described = descriptions_of(regions)
        names = tuple(sorted(described))
        return cls(names, described, _specificity({n: tokenize(n) for n in names}))


class _LabelSet:
    """The published label set and what both backends derive from label names."""

    def __init__(self, wordnet: Optional[WordNet], expansion: ExpansionWeights,
                 compound_cap: int):
        self.knowledge = PlaceKnowledge(wordnet) if wordnet is not None else None
        self.expander = LabelExpander(wordnet, expansion)
        self.compound_cap = compound_cap
        self.current = _Labels()

    @property
    def names(self) -> List[str]:
        return list(self.current.names)

    @property
    def described(self) -> Dict[str, str]:
        return self.current.described

    def knowledge_text(self, name: str) -> str:
        return self.knowledge.text(name) if self.knowledge else " ".join(tokenize(name))

    def compound_texts(self, name: str) -> List[str]:
        return (self.knowledge.compound_texts(name, cap=self.compound_cap)
                if self.knowledge else [])

    def expanded_text(self, name: str) -> str:
        tokens = tokenize(name)
        words = self.expander.expand(name) if self.expander.wordnet is not None else {}
        extra = sorted((w for w in words if w not in tokens), key=lambda w: (-words[w][0], w))
        return " ".join(tokens) + (": " + " ".join(extra) if extra else "")

    @staticmethod
    def lexical(labels: _Labels, phrase: str, name: str,
                description: str = "") -> Tuple[float, float, float]:
        """(spelling, number_match, number_mismatch) of a phrase against a label of `labels`
        (its description's words and numbers count as the name's when given)."""
        words = content_words(phrase)
        name_words = tokenize(name) + (content_words(description) if description else [])
        spelled = specific_spelling(words, name_words, labels.specificity)
        numbers, own = _numbers(phrase), _numbers(name) | _numbers(description)
        shared = bool(numbers & own)
        return spelled, float(shared), float(bool(numbers and own and not shared))


class SentenceFeatures:
    """Evidence from whole-phrase vectors (the sentence backend's `embed_phrases`)."""

    def __init__(self, embed_phrases: Embed, wordnet: Optional[WordNet] = None, *,
                 expansion: ExpansionWeights = ExpansionWeights(), compound_cap: int = 80,
                 compound_keep: int = 10):
        self.embed_phrases = embed_phrases
        self.compound_keep = compound_keep
        self.labels = _LabelSet(wordnet, expansion, compound_cap)
        # (name, description) -> its texts' vectors; the published (labels, vectors)
        self._cache: Dict[Tuple[str, str], Dict[str, np.ndarray]] = {}
        self._state: Tuple[_Labels, Dict[str, Dict[str, np.ndarray]]] = (_Labels(), {})

    def set_regions(self, regions: Sequence[Region]) -> None:
        """Encode the new or changed labels' texts, then publish the whole label set at once."""
        labels = _Labels.of(regions)
        new = [(n, labels.described[n]) for n in labels.names
               if (n, labels.described[n]) not in self._cache]
        self._cache.update(self._encode(new))  # an embedding failure here publishes nothing
        vectors = {n: self._cache[(n, labels.described[n])] for n in labels.names}
        self._cache = {(n, labels.described[n]): vectors[n] for n in labels.names}
        self._state = (labels, vectors)
        self.labels.current = labels

    def _texts(self, name: str, description: str) -> Dict[str, List[str]]:
        """One label's texts (name, knowledge, expanded, compounds, described)."""
        texts = {"name": [" ".join(tokenize(name))],
                 "knowledge": [self.labels.knowledge_text(name)],
                 "expanded": [self.labels.expanded_text(name)],
                 "compounds": self.labels.compound_texts(name)}
        if description:
            texts["described"] = [f"{' '.join(tokenize(name))}, {description}"]
        return texts

    def _encode(self, keys: Sequence[Tuple[str, str]]) -> Dict[Tuple[str, str],
                                                               Dict[str, np.ndarray]]:
        """The vectors of the labels' texts: the distinct texts of all labels in few large
        calls (the model pads less and is called less often than label by label)."""
        texts = {key: self._texts(*key) for key in keys}
        distinct = list(dict.fromkeys(t for groups in texts.values()
                                      for group in groups.values() for t in group))
        rows: Dict[str, np.ndarray] = {}
        for start in range(0, len(distinct), ENCODE_CHUNK):
            chunk = distinct[start:start + ENCODE_CHUNK]
            vectors = np.asarray(self.embed_phrases(chunk).vectors, dtype=np.float64)
            if len(vectors) != len(chunk):
                raise EmbeddingError(f"{len(chunk)} label texts gave {len(vectors)} vectors")
            rows.update(zip(chunk, vectors))
        dimension = len(next(iter(rows.values()))) if rows else 0
        encoded = {}
        for key, groups in texts.items():
            own = {kind: np.array([rows[t] for t in group]).reshape(len(group), dimension)
                   for kind, group in groups.items()}
            own["compounds"] = _closest(own["compounds"], own["knowledge"][0],
                                        self.compound_keep)
            encoded[key] = own
        return encoded

    def evidence(self, phrase: str) -> QueryEvidence:
        labels, vectors = self._state  # one published label set for the whole phrase
        query = self.embed_phrases([phrase])
        vector = np.asarray(query.vectors[0], dtype=np.float64)
        rows, described_rows, any_described = [], [], False
        for name in labels.names:
            own = vectors[name]
            compounds = float(np.max(own["compounds"] @ vector)) if len(own["compounds"]) else 0.0
            row = [float(own["name"][0] @ vector), float(own["knowledge"][0] @ vector),
                   float(own["expanded"][0] @ vector), compounds,
                   *_LabelSet.lexical(labels, phrase, name), 0.0]
            rows.append(row)
            description = labels.described[name]
            if description:
                any_described = True
                described_rows.append([float(own["described"][0] @ vector), *row[1:4],
                                       *_LabelSet.lexical(labels, phrase, name, description),
                                       0.0])
            else:
                described_rows.append(row)
        notes = [n for n in "; ".join(query.notes).split("; ") if n]
        return QueryEvidence(list(labels.names), _matrix(rows),
                             np.array(described_rows) if any_described else None,
                             list(query.oov), notes)


class WordFeatures:
    """Evidence from word vectors (word2vec): the word-by-word method for names and WordNet
    words (region_search.word_matching), SIF-weighted mean vectors for the knowledge texts."""

    def __init__(self, embed_words: Embed, wordnet: Optional[WordNet] = None, *,
                 expansion: ExpansionWeights = ExpansionWeights(), compound_cap: int = 80,
                 compound_keep: int = 10):
        self.embed_words = embed_words
        self.compound_keep = compound_keep
        self.labels = _LabelSet(wordnet, expansion, compound_cap)
        self._names = WordMatcher(embed_words, number_words=False)
        self._expanded = (WordMatcher(embed_words, wordnet=wordnet, weights=expansion,
                                            hubness=True, name_text_weight=0.0,
                                            number_words=False)
                          if wordnet is not None else self._names)
        self._query_words = (WordMatcher(embed_words, wordnet=wordnet, weights=expansion,
                                               hubness=True, name_text_weight=0.0,
                                               expand_query=True, number_words=False)
                             if wordnet is not None else None)
        self._described = WordMatcher(embed_words, number_words=False)
        self._words: Dict[str, Tuple[Optional[np.ndarray], float]] = {}
        self._cache: Dict[str, Dict[str, np.ndarray]] = {}  # name -> its knowledge texts' means
        self._state: Tuple[_Labels, Dict[str, Dict[str, np.ndarray]]] = (_Labels(), {})

    def set_regions(self, regions: Sequence[Region]) -> None:
        """Embed the new labels' words and texts, then publish the whole label set at once (the
        word-by-word recommenders below finish an interrupted update on the next call)."""
        labels = _Labels.of(regions)
        bare = [Region(name, 0.0, 0.0) for name in labels.names]
        self._names.set_regions(bare)
        if self._expanded is not self._names:
            self._expanded.set_regions(bare)
        if self._query_words is not None:
            self._query_words.set_regions(bare)
        self._described.set_regions([Region(n, 0.0, 0.0, description=labels.described[n])
                                     for n in labels.names])
        means = {}
        for name in labels.names:
            if name not in self._cache:  # an embedding failure here publishes nothing
                self._cache[name] = self._label_means(name)
            means[name] = self._cache[name]
        self._cache = dict(means)
        self._state = (labels, means)
        self.labels.current = labels

    def _label_means(self, name: str) -> Dict[str, np.ndarray]:
        texts = {"knowledge": [self.labels.knowledge_text(name)],
                 "compounds": self.labels.compound_texts(name)}
        self._learn_words([t for group in texts.values() for t in group])
        means = {key: self._rows(group) for key, group in texts.items()}
        if len(means["knowledge"]):
            means["compounds"] = _closest(means["compounds"], means["knowledge"][0],
                                          self.compound_keep)
        return means

    def _learn_words(self, texts: Sequence[str]) -> None:
        missing = sorted({w for t in texts for w in content_words(t)} - set(self._words))
        if missing:
            embedded = self.embed_words(missing)
            for word, vector, weight, found in zip(missing, embedded.vectors, embedded.weights,
                                                   embedded.found):
                self._words[word] = (np.asarray(vector, dtype=np.float64) if found else None,
                                     float(weight))

    def _mean(self, text: str) -> Optional[np.ndarray]:
        """The SIF-weighted mean of a text's word vectors, unit length (None: no vectors)."""
        pairs = [self._words[w] for w in content_words(text) if w in self._words]
        pairs = [(v, a) for v, a in pairs if v is not None]
        if not pairs:
            return None
        total = np.sum([a * v for v, a in pairs], axis=0)
        norm = np.linalg.norm(total)
        return total / norm if norm > 0 else None

    def _rows(self, texts: Sequence[str]) -> np.ndarray:
        means = [m for m in (self._mean(t) for t in texts) if m is not None]
        return np.array(means) if means else np.zeros((0, 0))

    def evidence(self, phrase: str) -> QueryEvidence:
        labels, label_means = self._state  # one published label set for the whole phrase
        names = self._scores(self._names, phrase)
        expanded = self._scores(self._expanded, phrase)
        query_words = (self._scores(self._query_words, phrase) if self._query_words is not None
                       else dict.fromkeys(labels.names, 0.0))
        described = self._scores(self._described, phrase)
        self._learn_words([phrase])
        query = self._mean(phrase)
        query = query if query is not None else np.zeros(0)
        rows, described_rows, any_described = [], [], False
        for name in labels.names:
            means = label_means[name]
            row = [names[name], _cosine(means["knowledge"], query),
                   expanded[name], _cosine(means["compounds"], query),
                   *_LabelSet.lexical(labels, phrase, name), query_words[name]]
            rows.append(row)
            description = labels.described[name]
            if description:
                any_described = True
                described_rows.append([described[name], *row[1:4],
                                       *_LabelSet.lexical(labels, phrase, name, description),
                                       query_words[name]])
            else:
                described_rows.append(row)
        embedded = self.embed_words(phrase_tokens(phrase))
        return QueryEvidence(list(labels.names), _matrix(rows),
                             np.array(described_rows) if any_described else None,
                             list(embedded.oov), [n for n in embedded.notes if n])

    @staticmethod
    def _scores(recommender: WordMatcher, phrase: str) -> Dict[str, float]:
        return {r.region.name: r.score for r in recommender.recommend(phrase, top_k=0).results}


def _matrix(rows: list) -> np.ndarray:
    """Evidence rows as a (labels, features) matrix, also when there are no labels."""
    return np.array(rows, dtype=np.float64).reshape(len(rows), len(FEATURES))


def _closest(rows: np.ndarray, anchor: np.ndarray, keep: int) -> np.ndarray:
    """The `keep` rows most similar to `anchor` (the compounds in the label's own sense:
    "coffee break" for a break room, not "jailbreak")."""
    if len(rows) <= keep or rows.shape[1] != anchor.shape[0]:
        return rows
    return rows[np.argsort(-(rows @ anchor))[:keep]]


def _cosine(rows: np.ndarray, vector: np.ndarray) -> float:
    if rows.size == 0 or rows.shape[1] != vector.shape[0]:
        return 0.0
    return float(np.max(rows @ vector))


class PlaceRecommender:
    """Ranks labelled places by weighted evidence; says when no labelled place matches.

    Args:
        features: SentenceFeatures or WordFeatures (the embedding backend's evidence).
        weights: RankingWeights (load_ranking_weights(backend) for the shipped ones).
        number_words: read numbers said as words as digits ("room three eleven" -> 311).
    """

    def __init__(self, features, weights: RankingWeights, *, number_words: bool = True):
        self.features = features
        self.weights = weights
        self.number_words = number_words
        self.regions: List[Region] = []  # one per place name

    def set_regions(self, regions: Sequence[Region]) -> None:
        """Use these regions from now on, one per place name (labels.distinct_places:
        a label file's place and a regions layer's of the same name are one place); label
        texts are encoded once. Nothing changes when it fails (e.g. the model still loads)."""
        places = distinct_places(regions)
        self.features.set_regions(places)
        self.regions = places

    def evidence(self, phrase: str) -> QueryEvidence:
        phrase_tokens(phrase)  # EmptyPhraseError for a phrase without words
        return self.features.evidence(spoken_numbers(phrase) if self.number_words else phrase)

    def scores(self, evidence: QueryEvidence, *, descriptions: bool = True) -> np.ndarray:
        """Each label's score (in evidence.names order)."""
        w = self.weights.vector()
        own = evidence.own @ w
        if not descriptions or evidence.described is None:
            return own
        return np.maximum(own, evidence.described @ w - self.weights.description_offset)

    def recommend(self, phrase: str, top_k: int = 3) -> Recommendation:
        """The `top_k` best regions (all when top_k <= 0), best first, or none with
        `matched` False when the best score's lead over the mean score is below the no-match
        margin."""
        places = {r.name: r for r in self.regions}
        evidence = self.evidence(phrase)
        scores = self.scores(evidence)
        by_name = dict(zip(evidence.names, scores))
        ranked = sorted((places[n] for n in evidence.names), key=lambda r: (-by_name[r.name],
                                                                           r.name))
        best = float(by_name[ranked[0].name]) if ranked else float("-inf")
        lead, gap = lead_and_gap(scores)
        if evidence.described is not None:  # a description never causes a "no match"
            lead = max(lead, lead_and_gap(self.scores(evidence, descriptions=False))[0])
        matched = bool(ranked) and lead >= self.weights.no_match_margin
        confidence = self.weights.confidence_of(lead, gap) if ranked else 0.0
        shown = ranked if top_k <= 0 else ranked[:top_k]
        results = [RankedRegion(r, float(by_name[r.name]), self._explain(evidence, r.name))
                   for r in shown]
        return Recommendation(phrase, results if matched else [], evidence.oov, evidence.notes,
                              matched=matched, best_score=best,
                              closest=results[:1] if not matched else [],
                              confidence=confidence,
                              sure=not confidence < self.weights.sure_confidence)

    def _explain(self, evidence: QueryEvidence, name: str) -> str:
        index = evidence.names.index(name)
        w = self.weights.vector()
        row = evidence.own[index]
        parts = [f"{f} {v:.2f}" for f, v, wt in zip(FEATURES, row, w) if v and wt]
        text = "evidence: " + ", ".join(parts) if parts else "no evidence"
        if evidence.described is not None:
            own, via = float(row @ w), float(evidence.described[index] @ w)
            if via - self.weights.description_offset > own:
                text += (f"; its description counted ({via:.2f} - "
                         f"{self.weights.description_offset:.2f} > {own:.2f})")
        return text
