"""What a kind of place is for, from WordNet (offline, no hand-written descriptions).

A label name such as `printer_room`, `circulation_desk` or `cafeteria` names a kind of place; what
people do there is in WordNet's definitions of its words: a printer is "an output device that
prints the results of data processing", a cafeteria "a restaurant where you serve yourself and pay
a cashier", a kitchen "a room equipped for preparing meals". `PlaceKnowledge.text(label)` writes
that as one sentence a sentence model can compare with a phrase ("print my slides"), and
`PlaceKnowledge.words(label)` gives the same knowledge as weighted words for the word-level method.

Which sense: a word of a place name usually means a thing or a place, not a person or a feeling
("printer" the device, not the pressman; "cold" the low temperature, not the illness), so senses
from WordNet's artifact, location, act, object, food, substance and possession files come before
the others, WordNet's own order within each group (its most frequent sense first).
The head word's hypernym (the kind of thing it is: cafeteria -> restaurant) is added too.
"""
from typing import Dict, List, Optional, Sequence, Tuple

from region_search.corpora import Synset, WordNet
from region_search.text_similarity import STOPWORDS, is_number, tokenize

__all__ = ["PlaceKnowledge", "PLACE_LEXNAMES"]

# WordNet noun lexicographer files a place name's words usually come from (wndb(5WN) lexnames):
# 4 act, 6 artifact, 13 food, 15 location, 17 object, 21 possession, 27 substance.
PLACE_LEXNAMES = (6, 15, 4, 17, 13, 21, 27)


class PlaceKnowledge:
    """Definitions of a label's words, chosen for a place (see the module docstring).

    Args:
        wordnet: the lexicon.
        senses: senses per word (the place-like ones first).
        hypernym: also give the head word's hypernym lemmas ("restaurant" for cafeteria).
    """

    def __init__(self, wordnet: WordNet, *, senses: int = 1, hypernym: bool = True):
        self.wordnet = wordnet
        self.senses = senses
        self.hypernym = hypernym
        self._cache: Dict[str, List[Tuple[str, Synset]]] = {}

    def synsets(self, label: str) -> List[Tuple[str, Synset]]:
        """(lemma, synset) pairs for the words of a label, longest WordNet lemmas first found
        left to right ("water fountain" as one), place-like senses first."""
        if label not in self._cache:
            tokens = tokenize(label)
            chosen: List[Tuple[str, Synset]] = []
            for lemma, synsets in _lemma_spans(self.wordnet, tokens):
                ranked = sorted(enumerate(synsets), key=lambda item: (_place_rank(item[1]),
                                                                       item[0]))
                chosen += [(lemma, synset) for _, synset in ranked[:self.senses]]
            self._cache[label] = chosen
        return self._cache[label]

    def text(self, label: str, name_text: Optional[str] = None) -> str:
        """"printer room: an output device that prints ...; an area within a building ..."
        (the name text alone when WordNet knows none of its words)."""
        name_text = name_text if name_text is not None else " ".join(tokenize(label))
        pieces = []
        for _, synset in self.synsets(label):
            if synset.definition and synset.definition not in pieces:
                pieces.append(synset.definition)
        kinds = self.kinds(label)
        if kinds:
            pieces.append("a kind of " + ", ".join(kinds))
        return f"{name_text}: {'; '.join(pieces)}" if pieces else name_text

    def kinds(self, label: str) -> List[str]:
        """Lemmas of the head word's hypernyms (the last word WordNet knows): cafeteria ->
        ["restaurant", "eating house", "eating place", "eatery"]."""
        found = self.synsets(label)
        if not self.hypernym or not found:
            return []
        head = found[-1][0]
        names: List[str] = []
        for lemma, synset in found:
            if lemma != head:
                continue
            for pos, offset in synset.hypernyms[:1]:
                for name in self.wordnet.synset(pos, offset).lemmas:
                    text = name.replace("_", " ")
                    if text not in names:
                        names.append(text)
        return names

    def compound_texts(self, label: str, *, cap: int = 80) -> List[str]:
        """WordNet's compound nouns that contain a word of the label, each with its definition
        ("coffee break: a short break from work for refreshments" for break_room): the things
        and activities a kind of place goes with. A word in more than `cap` compounds ("room",
        "area") says nothing specific and is skipped."""
        texts: List[str] = []
        for token in dict.fromkeys(tokenize(label)):
            if token in STOPWORDS or is_number(token):
                continue
            forms = self.wordnet.morphy(token, "n") or [token]
            lemmas = self.wordnet.compounds(forms[0])
            if len(lemmas) > cap:
                continue
            for lemma in lemmas:
                synsets = self.wordnet.synsets(lemma, "n")
                text = f"{lemma.replace('_', ' ')}: {synsets[0].definition}" if synsets else ""
                if text and text not in texts:
                    texts.append(text)
        return texts

    def words(self, label: str) -> Dict[str, Tuple[float, str]]:
        """word -> (1.0, origin): the content words of `text(label)` beyond the name's own."""
        own = set(tokenize(label))
        words: Dict[str, Tuple[float, str]] = {}
        for lemma, synset in self.synsets(label):
            for token in tokenize(synset.definition):
                if token not in STOPWORDS and not is_number(token) and token not in own:
                    words.setdefault(token, (1.0, f"definition of {lemma}"))
        for kind in self.kinds(label):
            for token in tokenize(kind):
                if token not in STOPWORDS and token not in own:
                    words.setdefault(token, (1.0, f"kind of place: {kind}"))
        return words


def _place_rank(synset: Synset) -> int:
    if synset.pos != "n":
        return len(PLACE_LEXNAMES) + 1
    return PLACE_LEXNAMES.index(synset.lexname) if synset.lexname in PLACE_LEXNAMES else len(
        PLACE_LEXNAMES)


def _lemma_spans(wordnet: WordNet, tokens: Sequence[str]) -> List[Tuple[str, List[Synset]]]:
    """(lemma, synsets) of the longest runs of tokens WordNet knows as one lemma, left to right
    (nouns first, then verbs and adjectives); tokens in no lemma are skipped."""
    spans = []
    start = 0
    while start < len(tokens):
        for end in range(len(tokens), start, -1):
            words = tokens[start:end]
            if all(is_number(t) or t in STOPWORDS for t in words):
                continue
            lemma, synsets = _lookup(wordnet, "_".join(words))
            if synsets:
                spans.append((lemma, synsets))
                start = end
                break
        else:
            start += 1
    return spans


def _lookup(wordnet: WordNet, lemma: str) -> Tuple[str, List[Synset]]:
    for pos in ("n", "v", "a"):
        for form in wordnet.morphy(lemma, pos):
            synsets = wordnet.synsets(form, pos)
            if synsets:
                return form, synsets
    return lemma, []
