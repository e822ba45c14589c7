"""The previous release's phrase method, kept as a baseline of the accuracy bench (the nodes rank
with region_search.ranking): labelled regions by whole-phrase vectors, not word by word.

`PhraseRegionRecommender` gives each label one text, its name words followed by its WordNet
expansion (word_matching.LabelExpander: synonyms, related words, definition words, strongest
first), e.g. "water fountain: bubbler drinking babble bubble ... jet provide public", encodes the
texts once (and again only when new labels appear), and scores a phrase by the cosine of its
vector with each label's. Room numbers identify rooms but barely move a sentence vector
("classroom 101" is as close to classroom_102 as to classroom_101), so, as in the word-level
method where numbers match by spelling only, a number of the phrase that a label carries adds
`number_weight` to its score and a label that carries only other numbers loses it.
Two more parts (weights chosen on the dev phrases, bench/nlp_region_accuracy.py --dev): the cosine
with the label's bare name text counts `name_text_weight` against the expanded text's
1 - `name_text_weight` (WordNet's senses of a proper name mislead: "grasp" is no robotics lab), and
`name_spelling_weight` x text_similarity.name_spelling_score adds an exact / fuzzy name match
("skirkanitch", "Charity's", "towne 311").
A label's optional description (Region.description: "the GRASP robotics laboratory") is part of
its name text ("grasp, the GRASP robotics laboratory"), of its expanded text and of the names the
spelling stage matches. Numbers said as words are read as digits first ("room three eleven" ->
"room 311", text_similarity.spoken_numbers), for the phrase vector and the number rule alike.
It is the region recommender's method when the embedding service serves phrase vectors (backend
"sentence"); with word2vec the word-level `WordMatcher` is better. Same interface:
`set_regions`, `recommend` -> `Recommendation`.
"""
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords, phrase_tokens
from region_search.errors import EmbeddingError
from region_search.labels import RankedRegion, Recommendation, Region, descriptions_of
from region_search.text_similarity import (
    content_words,
    is_number,
    name_spelling_score,
    spoken_numbers,
    tokenize,
)
from region_search.word_matching import ExpansionWeights, LabelExpander

__all__ = ["PhraseRegionRecommender"]

EmbedPhrases = Callable[[List[str]], EmbeddedWords]


class PhraseRegionRecommender:
    """Ranks labelled regions by the cosine of phrase vectors.

    Args:
        embed_phrases: phrases -> EmbeddedWords with one unit vector per phrase (the embedding
            service's client, or `SentenceEmbeddings.embed_phrases` in-process).
        wordnet: expands each label's text with WordNet words; None: the label's name words only.
        weights: expansion weights; here they only order the added words (strongest first).
        number_weight: added for a phrase number the label carries, subtracted from a label that
            carries numbers, none of them the phrase's (0: numbers count as text only).
        name_text_weight: share of the cosine with the bare name text (the rest: the expanded
            text); 0: the expanded text only.
        name_spelling_weight: weight of the name-spelling match (0: none).
        number_words: read numbers said as words as digits ("three eleven" -> 311).
    """

    method = "phrase"

    def __init__(self, embed_phrases: EmbedPhrases, *, wordnet: Optional[WordNet] = None,
                 weights: ExpansionWeights = ExpansionWeights(), number_weight: float = 0.2,
                 name_text_weight: float = 0.3, name_spelling_weight: float = 0.2,
                 number_words: bool = True):
        self.embed_phrases = embed_phrases
        self.number_weight = number_weight
        self.name_text_weight = name_text_weight
        self.name_spelling_weight = name_spelling_weight
        self.number_words = number_words
        self.expander = LabelExpander(wordnet, weights)
        self.regions: List[Region] = []
        self._texts: Dict[str, str] = {}
        self._vectors: Dict[str, np.ndarray] = {}
        self._name_vectors: Dict[str, np.ndarray] = {}
        self._described: Dict[str, str] = {}

    @staticmethod
    def name_text(name: str, description: str = "") -> str:
        """A label's bare name text: its name words, then its description if it has one."""
        text = " ".join(tokenize(name))
        return f"{text}, {description}" if description else text

    def label_text(self, name: str, description: str = "") -> str:
        """The text a label is encoded as: its name text, then its WordNet words."""
        tokens = tokenize(name) + tokenize(description)
        words = (self.expander.expand(name, description) if self.expander.wordnet is not None
                 else {})
        extra = sorted((w for w in words if w not in tokens), key=lambda w: (-words[w][0], w))
        return self.name_text(name, description) + (": " + " ".join(extra) if extra else "")

    def set_regions(self, regions: Sequence[Region]) -> None:
        """Use these regions from now on (only labels not seen before are encoded)."""
        described = descriptions_of(regions)
        names = sorted(name for name in described
                       if name not in self._vectors or self._described.get(name) != described[name])
        if names:
            texts = [self.label_text(name, described[name]) for name in names]
            bare = [self.name_text(name, described[name]) for name in names]
            with_names = texts + (bare if self.name_text_weight else [])
            embedded = self.embed_phrases(with_names)
            if len(embedded.vectors) != len(with_names):
                raise EmbeddingError(f"{len(with_names)} label texts gave "
                                     f"{len(embedded.vectors)} vectors")
            vectors = [np.asarray(v, dtype=np.float64) for v in embedded.vectors]
            for index, (name, text) in enumerate(zip(names, texts)):
                self._texts[name] = text
                self._described[name] = described[name]
                self._vectors[name] = vectors[index]
                self._name_vectors[name] = (vectors[len(names) + index] if self.name_text_weight
                                            else vectors[index])
        self.regions = list(regions)

    def recommend(self, phrase: str, top_k: int = 3) -> Recommendation:
        """The `top_k` best regions (all when top_k <= 0), best first; EmptyPhraseError if empty."""
        phrase_tokens(phrase)  # EmptyPhraseError for a phrase without words
        text = spoken_numbers(phrase) if self.number_words else phrase
        query = self.embed_phrases([text])
        vector = np.asarray(query.vectors[0], dtype=np.float64)
        numbers = {t for t in tokenize(text) if is_number(t)}
        words = content_words(text)
        scores, explanations = {}, {}
        for name in {r.name for r in self.regions}:
            share = self.name_text_weight
            cosine = ((1.0 - share) * float(self._vectors[name] @ vector)
                      + share * float(self._name_vectors[name] @ vector))
            bonus, why = self._number_bonus(numbers, name)
            spelled = (name_spelling_score(words, self.name_text(name, self._described[name]))
                       if self.name_spelling_weight else 0.0)
            if spelled > 0:
                why += f"; name spelled {spelled:.2f} (+{self.name_spelling_weight * spelled:.2f})"
            scores[name] = cosine + bonus + self.name_spelling_weight * spelled
            explanations[name] = self._explain(name, cosine) + why
        ranked = sorted(self.regions, key=lambda r: (-scores[r.name], r.name, r.x, r.y))
        if top_k > 0:
            ranked = ranked[:top_k]
        results = [RankedRegion(r, scores[r.name], explanations[r.name]) for r in ranked]
        notes = [note for note in "; ".join(query.notes).split("; ") if note]
        return Recommendation(phrase, results, list(query.oov), notes)

    def _number_bonus(self, numbers, name: str):
        """(score change, explanation) from the numbers of the phrase and of the label."""
        own = {t for t in tokenize(name) + tokenize(self._described.get(name, "")) if is_number(t)}
        if not numbers or not own or not self.number_weight:
            return 0.0, ""
        shared = sorted(numbers & own)
        if shared:
            return self.number_weight, f"; number {' '.join(shared)} matches (+{self.number_weight:.2f})"
        return -self.number_weight, (f"; number {' '.join(sorted(own))} is not "
                                     f"{' '.join(sorted(numbers))} (-{self.number_weight:.2f})")

    def _explain(self, name: str, score: float) -> str:
        text = self._texts[name]
        shown = text if len(text) <= 90 else text[:87].rsplit(" ", 1)[0] + " ..."
        return f"phrase cosine {score:.2f} with '{shown}'"
