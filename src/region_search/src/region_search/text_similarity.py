"""Words of phrases and label names, and similarity by spelling (no model needed).

- `tokenize("Towne_321's lab")` -> ["towne", "321", "lab"]: lower case, letters and digits split
  ("bio_lab", "towne321", "x-ray" all split), possessive 's dropped.
- `content_words` drops English function words (the usual stop-word list).
- `spelling_similarity(a, b)`: Dice coefficient of padded character trigrams in [0, 1]; numbers
  match only exactly (room 321 is not room 312).
- `name_spelling_score`: how much of a phrase spells a label's name ("skirkanitch hall" ->
  to_skirkanich), the name-matching stage both ranking methods add to their vector scores.
- `SpellingIndex`: the vocabulary word spelled most like a given word (an inverted trigram index),
  the last fallback for a word without a vector.
- `spoken_numbers("room three eleven")` -> "room 311": numbers said as words (two or more number
  words in a row, or a run with "hundred") become digits, as people say room numbers: digit by
  digit ("three one one"), in pairs ("three eleven", "three twenty-one") or in full ("three
  hundred and eleven"), with "oh" for a zero inside ("three oh four" -> 304). A single number
  word ("one of the labs") is left as it is.
"""
import re
from collections import defaultdict
from functools import lru_cache
from typing import Dict, FrozenSet, Iterable, List, Optional, Sequence, Tuple

__all__ = ["STOPWORDS", "tokenize", "content_words", "is_number", "trigrams",
           "spelling_similarity", "SpellingIndex", "string_baseline_score", "name_spelling_score",
           "spoken_numbers"]

# The common English stop-word list (function words only; no domain words).
STOPWORDS: FrozenSet[str] = frozenset("""
i me my myself we our ours ourselves you your yours yourself yourselves he him his himself she her
hers herself it its itself they them their theirs themselves what which who whom this that these
those am is are was were be been being have has had having do does did doing a an the and but if
or because as until while of at by for with about against between into through during before after
above below to from up down in out on off over under again further then once here there when where
why how all any both each few more most other some such no nor not only own same so than too very
s t can will just don should now d ll m o re ve y ain aren couldn didn doesn hadn hasn haven isn
ma mightn mustn needn shan shouldn wasn weren won wouldn please let
""".split())

_TOKEN = re.compile(r"[a-z]+|[0-9]+")
_POSSESSIVE = re.compile(r"['\u2019]s\b")
_APOSTROPHE = re.compile(r"['\u2019]")


def tokenize(text: str) -> List[str]:
    """Lower-case words and numbers of `text` (underscores, hyphens, digits all separate)."""
    text = _APOSTROPHE.sub("", _POSSESSIVE.sub("", text.lower()))
    return _TOKEN.findall(text)


def content_words(text_or_tokens) -> List[str]:
    """The tokens of a phrase without stop words; all tokens if every one is a stop word."""
    tokens = tokenize(text_or_tokens) if isinstance(text_or_tokens, str) else list(text_or_tokens)
    content = [token for token in tokens if token not in STOPWORDS]
    return content or tokens


def is_number(token: str) -> bool:
    return token.isdigit()


def trigrams(word: str) -> FrozenSet[str]:
    padded = f"#{word}#"
    return frozenset(padded[i:i + 3] for i in range(max(len(padded) - 2, 1)))


# the same few hundred label and phrase words are compared again and again
_recent_trigrams = lru_cache(maxsize=4096)(trigrams)


def spelling_similarity(a: str, b: str) -> float:
    """Dice coefficient of the padded character trigrams; numbers are equal or not at all."""
    if a == b:
        return 1.0
    if is_number(a) or is_number(b):
        return 0.0
    grams_a, grams_b = _recent_trigrams(a), _recent_trigrams(b)
    return 2.0 * len(grams_a & grams_b) / (len(grams_a) + len(grams_b))


def string_baseline_score(query_tokens: Sequence[str], label_tokens: Sequence[str]) -> float:
    """Plain string-similarity baseline: mean over query words of the best-spelled label word."""
    if not query_tokens or not label_tokens:
        return 0.0
    return sum(max(spelling_similarity(q, t) for t in label_tokens)
               for q in query_tokens) / len(query_tokens)


def name_spelling_score(query_words: Sequence[str], label: str,
                        min_similarity: float = 0.6) -> float:
    """Mean over the phrase's content words of the best spelling similarity to a word of the
    label's name (stop words of the name skipped: "to_skirkanich"); a similarity below
    `min_similarity` counts 0, numbers match only exactly. In [0, 1]."""
    names = content_words(label)
    if not query_words or not names:
        return 0.0
    total = 0.0
    for word in query_words:
        best = max(spelling_similarity(word, name) for name in names)
        total += best if best >= min_similarity else 0.0
    return total / len(query_words)


class SpellingIndex:
    """Finds the vocabulary word spelled most like a word, by shared character trigrams.

    Args:
        words: the vocabulary (e.g. the model's most frequent words; numbers are skipped).
        min_similarity: below this Dice similarity there is no match.
    """

    def __init__(self, words: Iterable[str], *, min_similarity: float = 0.6):
        self.min_similarity = min_similarity
        self._words: List[str] = []
        self._grams: List[FrozenSet[str]] = []
        self._postings: Dict[str, List[int]] = defaultdict(list)
        for word in words:
            if not word.isalpha() or len(word) < 3:
                continue
            grams = trigrams(word)
            index = len(self._words)
            self._words.append(word)
            self._grams.append(grams)
            for gram in grams:
                self._postings[gram].append(index)

    def __len__(self) -> int:
        return len(self._words)

    def nearest(self, word: str) -> Optional[Tuple[str, float]]:
        """(vocabulary word, similarity) of the best match at least `min_similarity`, or None."""
        if is_number(word) or len(word) < 3:
            return None
        grams = trigrams(word)
        shared: Dict[int, int] = defaultdict(int)
        for gram in grams:
            for index in self._postings.get(gram, ()):
                shared[index] += 1
        best, best_score = None, 0.0
        for index, count in shared.items():
            score = 2.0 * count / (len(grams) + len(self._grams[index]))
            # Ties go to the earlier (more frequent) word: the index is in vocabulary order.
            if score > best_score or (score == best_score and best is not None and index < best):
                best, best_score = index, score
        if best is None or best_score < self.min_similarity or self._words[best] == word:
            return None
        return self._words[best], best_score


_UNITS = {w: i for i, w in enumerate(
    "zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen "
    "fifteen sixteen seventeen eighteen nineteen".split())}
_TENS = {w: 10 * i for i, w in enumerate(
    "twenty thirty forty fifty sixty seventy eighty ninety".split(), start=2)}
# "twentyone": a tens word and a digit written together
_DIGIT_WORDS = "|".join(w for w, v in _UNITS.items() if 1 <= v <= 9)
_JOINED = re.compile(rf"^({'|'.join(_TENS)})({_DIGIT_WORDS})$")
_ZERO_WORDS = ("oh", "o")  # "three oh four": zero said as a letter, inside a number only
_WORD_OR_GAP = re.compile(r"[A-Za-z]+|[^A-Za-z]+")
_NUMBER_GAP = re.compile(r"^[ \t-]+$")  # what may separate number words: spaces, hyphens


def _number_word(word: str) -> bool:
    word = word.lower()
    return word in _UNITS or word in _TENS or word == "hundred" or bool(_JOINED.match(word))


def _groups(words: List[str]) -> Optional[str]:
    """Digits of a run of number words, or None when the run is no number."""
    if "hundred" in words:
        index = words.index("hundred")
        head, tail = words[:index], [w for w in words[index + 1:] if w != "and"]
        if len(head) != 1 or head[0] not in _UNITS or not 1 <= _UNITS[head[0]] <= 9:
            return None
        rest = _groups(tail) if tail else "0"
        if rest is None or int(rest) > 99 or "hundred" in tail:
            return None
        return str(_UNITS[head[0]] * 100 + int(rest))
    digits, index = "", 0
    while index < len(words):
        word = words[index]
        joined = _JOINED.match(word)
        if joined:
            digits += str(_TENS[joined.group(1)] + _UNITS[joined.group(2)])
        elif word in _TENS:
            following = words[index + 1] if index + 1 < len(words) else ""
            if following in _UNITS and 1 <= _UNITS[following] <= 9:
                digits += str(_TENS[word] + _UNITS[following])
                index += 1
            else:
                digits += str(_TENS[word])
        elif word in _UNITS:
            digits += str(_UNITS[word])
        elif word in _ZERO_WORDS:
            digits += "0"
        else:
            return None
        index += 1
    return digits


def spoken_numbers(text: str) -> str:
    """`text` with its spoken numbers written as digits (see the module docstring):
    "three eleven" -> "311", "three two one" -> "321", "three hundred and eleven" -> "311",
    "go to three-twenty-one" -> "go to 321"; single number words stay words."""
    parts = _WORD_OR_GAP.findall(text)
    out: List[str] = []
    index = 0
    while index < len(parts):
        if not _number_word(parts[index]):
            out.append(parts[index])
            index += 1
            continue
        # the longest run: number words separated by spaces/hyphens ("and" after "hundred")
        run, end, cursor = [parts[index].lower()], index + 1, index + 1
        while cursor + 1 < len(parts) and _NUMBER_GAP.match(parts[cursor]):
            word = parts[cursor + 1].lower()
            if _number_word(word) or (word in _ZERO_WORDS and cursor + 3 < len(parts)
                                      and _number_word(parts[cursor + 3])) or (
                    word == "and" and "hundred" in run
                                      and cursor + 3 < len(parts)
                                      and _number_word(parts[cursor + 3])):
                run.append(word)
                cursor += 2
                end = cursor
            else:
                break
        digits = _groups(run) if (len(run) >= 2 or _JOINED.match(run[0])) else None
        if digits is None:
            out.append(parts[index])
            index += 1
            continue
        out.append(digits)
        index = end
    return "".join(out)
