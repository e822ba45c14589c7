"""Word-by-word matching of a phrase with labels (the word2vec backend's evidence).

- `LabelExpander`: a label's words, plus (from WordNet) the synonyms, derivationally related words
  and definition words of the longest WordNet lemmas it contains: "water_fountain" also means
  "drinking fountain, bubbler: a public fountain to provide a jet of drinking water".
- `WordMatcher`: scores labels for a phrase word by word. Each query word finds its best match among a
  label's (weighted) words, by embedding cosine or by spelling (label-name words only: "towne",
  room numbers); the score is the SIF-weighted mean of these matches over the query's words.
  A share of it (`name_text_weight`, 0.3, chosen on the dev phrases by
  bench/nlp_region_accuracy.py --dev2; 0.5 before) is this score on the
  label's name words alone, so that WordNet's senses of a name ("grasp", "far") do not drown
  the name itself.
  Word vectors come from a callable (the embedding service's client, or a model in-process).
  Numbers said as words in a phrase are read as digits first ("room three eleven" -> "room 311",
  text_similarity.spoken_numbers).
"""
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords, phrase_tokens
from region_search.errors import EmbeddingError
from region_search.labels import RankedRegion, Recommendation, Region, descriptions_of
from region_search.text_similarity import (
    STOPWORDS,
    content_words,
    is_number,
    spelling_similarity,
    spoken_numbers,
    tokenize,
)

__all__ = ["ExpansionWeights", "LabelExpander", "WordMatcher"]

EmbedWords = Callable[[List[str]], EmbeddedWords]


@dataclass(frozen=True)
class ExpansionWeights:
    """How much a label word counts, by where it comes from."""

    name: float = 1.0
    synonym: float = 0.9
    derived: float = 0.8
    definition: float = 0.6
    senses: int = 2  # WordNet senses used per lemma (most frequent first)
    description: float = 1.0  # the content words of a label's description (given by a user)
    expand_description: bool = True  # also expand the description's words with WordNet


class LabelExpander:
    """A label's words with weights and origins, expanded with WordNet (when given)."""

    def __init__(self, wordnet: Optional[WordNet] = None,
                 weights: ExpansionWeights = ExpansionWeights()):
        self.wordnet = wordnet
        self.weights = weights

    def expand(self, label: str, description: str = "") -> Dict[str, Tuple[float, str]]:
        """word -> (weight, origin) for a label name such as "vending_machines" (and its
        optional description, whose content words count `weights.description`)."""
        tokens = tokenize(label)
        words: Dict[str, Tuple[float, str]] = {}
        for token in tokens:
            _add(words, token, self.weights.name, "name")
        described = [t for t in tokenize(description) if t not in STOPWORDS]
        for token in described:
            _add(words, token, self.weights.description, "description")
        for _, _, lemma, synsets in self.lemma_spans(tokens):
            self._add_synsets(words, lemma, synsets)
        if self.weights.expand_description and description:
            for _, _, lemma, synsets in self.lemma_spans(tokenize(description)):
                self._add_synsets(words, lemma, synsets)
        return words

    def expand_words(self, tokens: Sequence[str]) -> List[Dict[str, Tuple[float, str]]]:
        """Per token: the WordNet words (weight, origin) of the lemma covering it, if any."""
        expansions: List[Dict[str, Tuple[float, str]]] = [{} for _ in tokens]
        for start, end, lemma, synsets in self.lemma_spans(tokens):
            words: Dict[str, Tuple[float, str]] = {}
            self._add_synsets(words, lemma, synsets)
            for index in range(start, end):
                expansions[index] = {w: v for w, v in words.items() if w != tokens[index]}
        return expansions

    def lemma_spans(self, tokens: Sequence[str]) -> List[Tuple[int, int, str, list]]:
        """(start, end, lemma, synsets): the longest runs of tokens WordNet knows as one lemma
        ("water fountain", "work out"), left to right; tokens in no lemma are skipped."""
        spans = []
        start = 0
        while self.wordnet is not None and start < len(tokens):
            for end in range(len(tokens), start, -1):
                if all(is_number(t) or t in STOPWORDS for t in tokens[start:end]):
                    continue
                lemma, synsets = self._lookup("_".join(tokens[start:end]))
                if synsets:
                    spans.append((start, end, lemma, synsets))
                    start = end
                    break
            else:
                start += 1
        return spans

    def _lookup(self, lemma: str):
        for pos in ("n", "v", "a"):
            for form in self.wordnet.morphy(lemma, pos):
                synsets = self.wordnet.synsets(form, pos)[:self.weights.senses]
                if synsets:
                    return form, synsets
        return lemma, []

    def _add_synsets(self, words, lemma: str, synsets) -> None:
        w = self.weights
        for synset in synsets:
            for name in synset.lemmas:
                for token in tokenize(name):
                    _add(words, token, w.synonym, f"synonym '{name}' of {lemma}")
            for pos, offset in synset.derived:
                for name in self.wordnet.synset(pos, offset).lemmas:
                    for token in tokenize(name):
                        _add(words, token, w.derived, f"related '{name}' of {lemma}")
            for token in tokenize(synset.definition):
                if token not in STOPWORDS and not is_number(token):
                    _add(words, token, w.definition, f"definition of {lemma}")


def _add(words: Dict[str, Tuple[float, str]], token: str, weight: float, origin: str) -> None:
    if token not in words or words[token][0] < weight:
        words[token] = (weight, origin)


class WordMatcher:
    """Ranks labelled regions for a phrase.

    Args:
        embed_words: words -> EmbeddedWords (unit vectors, SIF weights, fallback notes); None for
            exact word matches and spelling only.
        wordnet: expands labels (and, with `expand_query`, the query's words) with WordNet
            synonyms, related words and definitions; None: the words as they are.
        use_spelling: also match query words to label-name words by spelling.
        expand_query: a query word may also match through its own WordNet words ("latte" ->
            "coffee"), counted with their expansion weight.
        method: "align" (each query word's best label word) or "mean" (cosine of weighted means).
        weights: how much expanded words count.
        name_text_weight: with `wordnet`, the share of the score computed on the label's name
            words (and description words) alone (the rest: on the expanded words); 0: the
            expanded words only.
        number_words: read numbers said as words as digits ("three eleven" -> 311).
    """

    def __init__(self, embed_words: Optional[EmbedWords], *, wordnet: Optional[WordNet] = None,
                 use_spelling: bool = True, expand_query: bool = False, method: str = "align",
                 weights: ExpansionWeights = ExpansionWeights(), min_spelling: float = 0.5,
                 hubness: bool = False, name_text_weight: float = 0.3,
                 number_words: bool = True):
        if method not in ("align", "mean"):
            raise EmbeddingError(f"unknown method {method!r}; use 'align' or 'mean'")
        self.embed_words = embed_words
        self.expander = LabelExpander(wordnet, weights)
        self.use_spelling = use_spelling
        self.expand_query = expand_query and wordnet is not None
        self.method = method
        self.min_spelling = min_spelling
        self.hubness = hubness and embed_words is not None
        self.number_words = number_words
        self._hub: Dict[str, float] = {}
        self._hub_labels: Tuple[str, ...] = ()
        self.regions: List[Region] = []
        # label -> (words, weights, origins, name tokens)
        self._labels: Dict[str, Tuple[List[str], np.ndarray, List[str], List[str]]] = {}
        self._described: Dict[str, str] = {}  # label -> the description its words came from
        self._vectors: Dict[str, Optional[np.ndarray]] = {}
        self.name_text_weight = name_text_weight if wordnet is not None else 0.0
        # The same ranking on the label names alone (its share: name_text_weight).
        self._names: Optional[WordMatcher] = None
        if self.name_text_weight:
            self._names = WordMatcher(embed_words, use_spelling=use_spelling, method=method,
                                      weights=weights, min_spelling=min_spelling,
                                      hubness=hubness, number_words=number_words)

    def set_regions(self, regions: Sequence[Region]) -> None:
        """Use these regions from now on (label words are expanded and embedded once)."""
        described = descriptions_of(regions)
        names = sorted(name for name in described
                       if name not in self._labels or self._described.get(name) != described[name])
        expansions = {name: self.expander.expand(name, described[name]) for name in names}
        self._embed_missing([w for words in expansions.values() for w in words])
        for name, words in expansions.items():
            ordered = sorted(words)
            self._labels[name] = (ordered, np.array([words[w][0] for w in ordered]),
                                  [words[w][1] for w in ordered],
                                  tokenize(name) + content_words(described[name])
                                  if described[name] else tokenize(name))
            self._described[name] = described[name]
        self.regions = list(regions)
        if self._names is not None:
            self._names.set_regions(regions)
        label_set = tuple(sorted(described.items()))
        if self.hubness and (names or label_set != self._hub_labels):  # only when labels change
            self._hub = self._hub_levels(sorted(described))
            self._hub_labels = label_set

    def _hub_levels(self, names: List[str]) -> Dict[str, float]:
        """Per label: its mean best match with the other labels' words (CSLS-style hubness;
        a label with many, generic words matches anything a little and is corrected down)."""
        levels = {}
        for name in names:
            own = set(self._labels[name][0])
            background = sorted({w for other in names if other != name
                                 for w in self._labels[other][0]} - own)
            vectors = [self._vectors.get(w) for w in background]
            rows = np.array([v for v in vectors if v is not None])
            if len(rows) == 0:
                levels[name] = 0.0
                continue
            best, _ = self._matches(["?"] * len(rows), rows, name)
            levels[name] = float(np.mean(best))
        return levels

    def _embed_missing(self, words: Sequence[str]) -> None:
        missing = sorted(set(words) - set(self._vectors))
        if not missing or self.embed_words is None:
            return
        embedded = self.embed_words(missing)
        for word, vector, found in zip(missing, embedded.vectors, embedded.found):
            self._vectors[word] = np.asarray(vector) if found else None

    def recommend(self, phrase: str, top_k: int = 3) -> Recommendation:
        """The `top_k` best regions (all when top_k <= 0), best first; EmptyPhraseError if empty."""
        scored, query = self._scores(phrase)
        if self._names is not None:
            share = self.name_text_weight
            names, _ = self._names._scores(phrase, query)  # the same query vectors, no new call
            scored = {name: ((1.0 - share) * score + share * names[name][0],
                             f"{why}; on the name alone {names[name][0]:.2f} (share {share:.2f})")
                      for name, (score, why) in scored.items()}
        ranked = sorted(self.regions, key=lambda r: (-scored[r.name][0], r.name, r.x, r.y))
        if top_k > 0:
            ranked = ranked[:top_k]
        results = [RankedRegion(r, scored[r.name][0], scored[r.name][1]) for r in ranked]
        return Recommendation(phrase, results, list(query.oov), [n for n in query.notes if n])

    def _scores(self, phrase: str, embedded_query: Optional[EmbeddedWords] = None):
        """({label: (score, explanation)}, the query's EmbeddedWords); `embedded_query`: the
        phrase's words already embedded (used when there is no query expansion)."""
        phrase = spoken_numbers(phrase) if self.number_words else phrase
        tokens = phrase_tokens(phrase)
        everything = tokenize(phrase)
        positions = [i for i, t in enumerate(everything) if t not in STOPWORDS]
        positions = positions if len(positions) == len(tokens) else list(range(len(everything)))
        expansions: List[Dict[str, Tuple[float, str]]] = [{} for _ in tokens]
        if self.expand_query:
            by_position = self.expander.expand_words(everything)
            expansions = [by_position[i] for i in positions]
        extra = sorted({w for e in expansions for w in e} - set(tokens))
        if self.embed_words is not None and embedded_query is not None and not extra:
            query = embedded_query
            rows = np.where(query.found[:, None], query.vectors, 0.0)
        elif self.embed_words is not None:
            embedded = self.embed_words(list(tokens) + extra)
            query = EmbeddedWords(tokens, embedded.vectors[:len(tokens)],
                                  embedded.weights[:len(tokens)], embedded.notes[:len(tokens)],
                                  [w for w in embedded.oov if w in tokens])
            rows = np.where(embedded.found[:, None], embedded.vectors, 0.0)
        else:
            query = EmbeddedWords(tokens, np.zeros((len(tokens), 1)), np.ones(len(tokens)),
                                  [""] * len(tokens), [])
            rows = None
        row_words = list(tokens) + extra
        scored = {name: self._score(query, expansions, row_words, rows, name)
                  for name in {r.name for r in self.regions}}
        return scored, query

    def _matches(self, row_words, rows, name) -> Tuple[np.ndarray, np.ndarray]:
        """(best weighted similarity, index of the label word) of every row word to a label."""
        words, weights, _, _ = self._labels[name]
        # Equal words match fully, with or without vectors (a word the model lacks included).
        sims = np.array([[float(r == w) for w in words] for r in row_words])
        if rows is not None:
            vectors = [self._vectors.get(w) for w in words]
            usable = [i for i, v in enumerate(vectors) if v is not None]
            if usable:
                cosines = rows @ np.array([vectors[i] for i in usable]).T
                sims[:, usable] = np.maximum(sims[:, usable], cosines)
        sims = sims * weights[None, :]
        best = sims.argmax(axis=1)
        return sims[np.arange(len(row_words)), best], best

    def _score(self, query: EmbeddedWords, expansions, row_words, rows, name) -> Tuple[float, str]:
        words, weights, origins, name_tokens = self._labels[name]
        if self.method == "mean" and rows is not None:
            return self._mean_score(query, name)
        best, where = self._matches(row_words, rows, name)
        row_of = {w: i for i, w in enumerate(row_words)}
        matches = best[:len(query.words)].copy()
        reasons = [f"{q}~{words[where[i]]} ({origins[where[i]]})" if matches[i] > 0 else ""
                   for i, q in enumerate(query.words)]
        for i, word in enumerate(query.words):
            for extra, (factor, origin) in expansions[i].items():
                row = row_of[extra]
                if factor * best[row] > matches[i]:
                    matches[i] = factor * best[row]
                    reasons[i] = (f"{word}->{extra} ({origin})~{words[where[row]]} "
                                  f"({origins[where[row]]})")
            if self.use_spelling:
                spelled, token = max((spelling_similarity(word, t), t) for t in name_tokens)
                if spelled >= self.min_spelling and spelled > matches[i]:
                    matches[i] = spelled
                    reasons[i] = f"{word}~{token} (spelling)"
        score = float(np.sum(query.weights * matches) / np.sum(query.weights))
        explanation = "; ".join(f"{r} {m:.2f}" for r, m in zip(reasons, matches) if r and m > 0)
        if self.hubness and query.found.any():
            # Only query words with vectors take part in vector matching, so only their share
            # of the weight is corrected (a word nothing can embed matches no label either).
            share = float(np.sum(query.weights[query.found]) / np.sum(query.weights))
            score -= share * self._hub.get(name, 0.0)
            explanation += f" (minus label hubness {share * self._hub.get(name, 0.0):.2f})"
        return score, explanation

    def _mean_score(self, query: EmbeddedWords, name: str) -> Tuple[float, str]:
        words, weights, _, _ = self._labels[name]
        usable = [(w, self._vectors.get(word)) for w, word in zip(weights, words)
                  if self._vectors.get(word) is not None]
        if not usable:
            return 0.0, "no label word has a vector"
        label = np.sum([w * v for w, v in usable], axis=0)
        phrase = np.sum(query.weights[:, None] * query.vectors, axis=0)
        denominator = np.linalg.norm(label) * np.linalg.norm(phrase)
        score = float(label @ phrase / denominator) if denominator > 0 else 0.0
        return score, f"cosine of mean vectors over {len(usable)} label words"
