"""Training corpora for word vectors and the WordNet lexicon (pure Python, no downloads).

- The Brown corpus in NLTK's format (`brown/ca01` ... files of `word/tag` tokens, one sentence a
  line): read straight from NLTK's `brown.zip` or an extracted `brown/` folder; `find_brown()`
  looks where NLTK looks (NLTK_DATA, ~/nltk_data, /usr/share/nltk_data ...).
- WordNet 3.0 from Debian's `wordnet-base` package (/usr/share/wordnet): `WordNet` reads its
  index and data files; `WordNet.gloss_sentences()` gives one sentence per synset (its lemmas,
  definition and examples), the corpus a fresh machine always has.
"""
import hashlib
import os
import zipfile
from pathlib import Path
from typing import Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple

from region_search.errors import CorpusError
from region_search.text_similarity import tokenize

__all__ = ["DEFAULT_WORDNET_DIR", "find_brown", "brown_sentences", "file_fingerprint",
           "Synset", "WordNet"]

DEFAULT_WORDNET_DIR = "/usr/share/wordnet"
POS_FILES = {"n": "noun", "v": "verb", "a": "adj", "r": "adv"}
# WordNet's morphological rules (morphy): suffix -> replacement, per part of speech.
_DETACHMENT = {
    "n": [("s", ""), ("ses", "s"), ("xes", "x"), ("zes", "z"), ("ches", "ch"), ("shes", "sh"),
          ("men", "man"), ("ies", "y")],
    "v": [("s", ""), ("ies", "y"), ("es", "e"), ("es", ""), ("ed", "e"), ("ed", ""), ("ing", "e"),
          ("ing", "")],
    "a": [("er", ""), ("est", ""), ("er", "e"), ("est", "e")],
    "r": [],
}


def find_brown(path: str = "") -> Optional[Path]:
    """The Brown corpus: `path` (a brown.zip or a folder with the files), else where NLTK looks.

    Returns None when no Brown corpus is found (and `path` is empty); raises CorpusError when
    `path` is given but holds no Brown corpus.
    """
    if path:
        found = _brown_at(Path(path).expanduser())
        if found is None:
            raise CorpusError(f"no Brown corpus at {path!r} (want brown.zip or a folder of ca01...)")
        return found
    roots = [p for p in os.environ.get("NLTK_DATA", "").split(os.pathsep) if p]
    roots += [str(Path.home() / "nltk_data"), "/usr/share/nltk_data", "/usr/local/share/nltk_data",
              "/usr/lib/nltk_data", "/usr/local/lib/nltk_data"]
    for root in roots:
        for candidate in (Path(root) / "corpora" / "brown", Path(root) / "corpora" / "brown.zip"):
            found = _brown_at(candidate)
            if found is not None:
                return found
    return None


def _brown_at(path: Path) -> Optional[Path]:
    if path.is_file() and zipfile.is_zipfile(path):
        return path
    if path.is_dir():
        for folder in (path, path / "brown", path / "corpora" / "brown"):
            if (folder / "ca01").is_file():
                return folder
    return None


def brown_sentences(source: Path) -> Iterator[List[str]]:
    """Sentences of the Brown corpus as lists of tokens (see `text_similarity.tokenize`)."""
    source = Path(source)
    try:
        for text in _brown_texts(source):
            for line in text.splitlines():
                words = [token.rsplit("/", 1)[0] for token in line.split()]
                tokens = tokenize(" ".join(words))
                if tokens:
                    yield tokens
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError) as err:
        raise CorpusError(f"cannot read the Brown corpus at {source}: {err}") from err


def _brown_texts(source: Path) -> Iterator[str]:
    if source.is_file():
        with zipfile.ZipFile(source) as archive:
            names = sorted(n for n in archive.namelist() if _is_brown_text(n.rsplit("/", 1)[-1]))
            if not names:
                raise CorpusError(f"{source} holds no Brown text files (ca01 ...)")
            for name in names:
                yield archive.read(name).decode("latin-1")
        return
    files = sorted(p for p in source.iterdir() if _is_brown_text(p.name))
    if not files:
        raise CorpusError(f"{source} holds no Brown text files (ca01 ...)")
    for path in files:
        yield path.read_text(encoding="latin-1")


def _is_brown_text(name: str) -> bool:
    return len(name) == 4 and name[0] == "c" and name[1].isalpha() and name[2:].isdigit()


def file_fingerprint(paths: Sequence[Path]) -> str:
    """sha256 over the files' names, sizes and contents (what a cached model was trained on)."""
    digest = hashlib.sha256()
    for path in sorted(Path(p) for p in paths):
        digest.update(f"{path.name}:{path.stat().st_size}\n".encode())
        with open(path, "rb") as stream:
            for block in iter(lambda: stream.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


class Synset(NamedTuple):
    """One WordNet synset: its lemmas, definition, examples and derivationally related words."""

    pos: str
    offset: int
    lemmas: Tuple[str, ...]
    definition: str
    examples: Tuple[str, ...]
    derived: Tuple[Tuple[str, int], ...]  # (pos, offset) of derivationally related synsets
    lexname: int = 0  # lexicographer file number (nouns: 6 artifact, 15 location, 18 person ...)
    hypernyms: Tuple[Tuple[str, int], ...] = ()  # (pos, offset) of its hypernyms (instance too)


class WordNet:
    """WordNet 3.0 as Debian's wordnet-base installs it (index.* and data.* files).

    Args:
        directory: the folder of the files (default /usr/share/wordnet).
    """

    def __init__(self, directory: str = DEFAULT_WORDNET_DIR):
        self.directory = Path(directory)
        missing = [n for n in POS_FILES.values() if not (self.directory / f"data.{n}").is_file()]
        if missing:
            raise CorpusError(f"no WordNet data in {self.directory} (missing data.{missing[0]}); "
                              "install Debian's wordnet-base package")
        self._index: Optional[Dict[str, Dict[str, List[int]]]] = None
        self._exceptions: Optional[Dict[str, Dict[str, List[str]]]] = None
        self._cache: Dict[Tuple[str, int], Synset] = {}
        self._compounds: Optional[Dict[str, List[str]]] = None

    def data_files(self) -> List[Path]:
        return [self.directory / f"data.{name}" for name in POS_FILES.values()]

    # -- corpus ------------------------------------------------------------------------------
    def gloss_sentences(self) -> Iterator[List[str]]:
        """One token list per synset: lemma words, then the definition and examples."""
        for pos in POS_FILES:
            for synset in self._iter_synsets(pos):
                tokens = [t for lemma in synset.lemmas for t in tokenize(lemma)]
                tokens += tokenize(synset.definition)
                for example in synset.examples:
                    tokens += tokenize(example)
                yield tokens

    def _iter_synsets(self, pos: str) -> Iterator[Synset]:
        with open(self.directory / f"data.{POS_FILES[pos]}", "rb") as stream:
            for raw in stream:
                if not raw.startswith(b"  "):
                    yield _parse_synset(raw.decode("utf-8", errors="replace"))

    # -- lexicon -----------------------------------------------------------------------------
    def synsets(self, lemma: str, pos: str = "n") -> List[Synset]:
        """Synsets of a lemma ("water_fountain", "printer") in WordNet's sense order."""
        offsets = self._load_index()[pos].get(lemma.lower(), [])
        return [self.synset(pos, offset) for offset in offsets]

    def synset(self, pos: str, offset: int) -> Synset:
        key = (pos, offset)
        if key not in self._cache:
            with open(self.directory / f"data.{POS_FILES[pos]}", "rb") as stream:
                stream.seek(offset)  # a synset's offset is its byte offset in the data file
                self._cache[key] = _parse_synset(stream.readline().decode("utf-8", "replace"))
        return self._cache[key]

    def compounds(self, word: str) -> List[str]:
        """Noun lemmas of two or more words that contain `word` as one of them ("break" ->
        "coffee_break", "lunch_break", ...), in index order."""
        if self._compounds is None:
            table: Dict[str, List[str]] = {}
            for lemma in self._load_index()["n"]:
                parts = lemma.split("_")
                if len(parts) > 1:
                    for part in dict.fromkeys(parts):
                        table.setdefault(part, []).append(lemma)
            self._compounds = table
        return list(self._compounds.get(word.lower(), []))

    def morphy(self, word: str, pos: str = "n") -> List[str]:
        """Base forms of `word` that WordNet knows (exceptions, then suffix rules), as morphy."""
        word = word.lower()
        index = self._load_index()[pos]
        exceptions = self._load_exceptions()[pos].get(word, [])
        forms = [word] + exceptions
        forms += [word[:-len(suffix)] + ending for suffix, ending in _DETACHMENT[pos]
                  if word.endswith(suffix) and len(word) > len(suffix)]
        seen: List[str] = []
        for form in forms:
            if form in index and form not in seen:
                seen.append(form)
        return seen

    def _load_index(self) -> Dict[str, Dict[str, List[int]]]:
        if self._index is None:
            index: Dict[str, Dict[str, List[int]]] = {}
            for pos, name in POS_FILES.items():
                index[pos] = entries = {}
                with open(self.directory / f"index.{name}", encoding="utf-8",
                          errors="replace") as stream:
                    for line in stream:
                        if line.startswith("  "):
                            continue
                        fields = line.split()
                        count = int(fields[2])
                        entries[fields[0]] = [int(f) for f in fields[len(fields) - count:]]
            self._index = index
        return self._index

    def _load_exceptions(self) -> Dict[str, Dict[str, List[str]]]:
        if self._exceptions is None:
            self._exceptions = {}
            for pos, name in POS_FILES.items():
                table: Dict[str, List[str]] = {}
                path = self.directory / f"{name}.exc"
                if path.is_file():
                    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
                        fields = line.split()
                        if len(fields) >= 2:
                            table[fields[0]] = fields[1:]
                self._exceptions[pos] = table
        return self._exceptions


def _parse_synset(line: str) -> Synset:
    """One line of a WordNet data file (see wndb(5WN))."""
    head, _, gloss = line.partition("|")
    fields = head.split()
    offset, pos = int(fields[0]), fields[2]
    pos = "a" if pos == "s" else pos
    count = int(fields[3], 16)
    lemmas = tuple(_strip_marker(fields[4 + 2 * i]) for i in range(count))
    cursor = 4 + 2 * count
    pointer_count = int(fields[cursor])
    derived, hypernyms = [], []
    for i in range(pointer_count):
        symbol, target, target_pos = fields[cursor + 1 + 4 * i: cursor + 4 + 4 * i]
        pointer = ("a" if target_pos == "s" else target_pos, int(target))
        if symbol == "+":
            derived.append(pointer)
        elif symbol in ("@", "@i"):
            hypernyms.append(pointer)
    parts = [part.strip() for part in gloss.strip().split(";")]
    definition = "; ".join(p for p in parts if not p.startswith('"'))
    examples = tuple(p.strip('"') for p in parts if p.startswith('"'))
    return Synset(pos, offset, lemmas, definition, examples, tuple(derived), int(fields[1]),
                  tuple(hypernyms))


def _strip_marker(lemma: str) -> str:
    # Adjectives may carry a syntactic marker: "big(a)", "galore(ip)".
    return lemma.split("(", 1)[0].lower()
