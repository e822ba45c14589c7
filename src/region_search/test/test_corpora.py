"""Corpus readers: Brown in NLTK's format (zip, folder, NLTK_DATA) and Debian's WordNet files."""
import zipfile
from pathlib import Path

import pytest

from region_search.corpora import WordNet, brown_sentences, file_fingerprint, find_brown
from region_search.errors import CorpusError, EmbeddingError

CA01 = ("\n\n\tThe/at Fulton/np-tl County/nn-tl Grand/jj-tl Jury/nn-tl said/vbd Friday/nr ./.\n\n"
        "\n\tThe/at jury/nn further/rbr said/vbd in/in term-end/nn presentments/nns ./.\n")
CA02 = "\n\n\tRoom/nn 321/cd of/in Towne's/np$ lab/nn ,/, 1/2/cd of/in it/pps ./.\n"
EXPECTED = [["the", "fulton", "county", "grand", "jury", "said", "friday"],
            ["the", "jury", "further", "said", "in", "term", "end", "presentments"],
            ["room", "321", "of", "towne", "lab", "1", "2", "of", "it"]]


def make_brown_zip(path: Path) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("brown/", "")
        archive.writestr("brown/README", "not a text file")
        archive.writestr("brown/ca02", CA02)
        archive.writestr("brown/ca01", CA01)
    return path


def test_brown_sentences_from_zip_and_folder_give_the_same_tokens(tmp_path):
    archive = make_brown_zip(tmp_path / "brown.zip")
    assert list(brown_sentences(archive)) == EXPECTED
    folder = tmp_path / "extracted" / "brown"
    folder.mkdir(parents=True)
    (folder / "ca01").write_text(CA01)
    (folder / "ca02").write_text(CA02)
    (folder / "cats.txt").write_text("ca01 news\n")
    assert list(brown_sentences(find_brown(str(tmp_path / "extracted")))) == EXPECTED


def test_find_brown_looks_in_nltk_data_and_refuses_a_wrong_path(tmp_path, monkeypatch):
    corpora = tmp_path / "nltk" / "corpora"
    corpora.mkdir(parents=True)
    make_brown_zip(corpora / "brown.zip")
    monkeypatch.setenv("NLTK_DATA", str(tmp_path / "nltk"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert find_brown() == corpora / "brown.zip"
    with pytest.raises(CorpusError, match="no Brown corpus at '.*nowhere'"):
        find_brown(str(tmp_path / "nowhere"))
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("brown/README", "x")
    with pytest.raises(CorpusError, match="no Brown text files"):
        list(brown_sentences(empty))


def test_the_real_brown_corpus_starts_with_the_fulton_county_story(shared_data_dir):
    archive = shared_data_dir / "corpora" / "brown.zip"
    sentences = brown_sentences(archive)
    first = next(sentences)
    assert first[:8] == ["the", "fulton", "county", "grand", "jury", "said", "friday", "an"]
    with zipfile.ZipFile(archive) as opened:  # the corpus has 500 texts, ca01 ... cr09
        assert sum(1 for n in opened.namelist() if n.startswith("brown/c") and len(n) == 10) == 500


def test_fingerprint_changes_with_content(tmp_path):
    a = tmp_path / "a"
    a.write_text("one")
    first = file_fingerprint([a])
    a.write_text("two")
    assert file_fingerprint([a]) != first


@pytest.mark.wordnet
def test_wordnet_synsets_morphy_and_glosses_match_wordnet_3():
    wordnet = WordNet()
    fountain = wordnet.synsets("water_fountain")[0]
    assert {"drinking_fountain", "water_fountain", "bubbler"} == set(fountain.lemmas)
    assert "drinking water" in fountain.definition
    assert wordnet.morphy("restrooms") == ["restroom"]
    assert wordnet.morphy("mice") == ["mouse"]  # from the exception list noun.exc
    assert "vending_machine" in wordnet.morphy("vending_machines")
    printer = wordnet.synsets("printer")
    derived = {lemma for s in printer for p, o in s.derived for lemma in wordnet.synset(p, o).lemmas}
    assert "print" in derived


@pytest.mark.wordnet
def test_wordnet_gloss_corpus_has_one_sentence_per_synset():
    # WordNet 3.0 has 117,659 synsets (82,115 nouns, 13,767 verbs, 18,156 adjectives, 3,621 adverbs).
    assert sum(1 for _ in WordNet().gloss_sentences()) == 117_659


def test_missing_wordnet_is_a_clear_error(tmp_path):
    with pytest.raises(CorpusError, match="install Debian's wordnet-base") as caught:
        WordNet(str(tmp_path))
    assert isinstance(caught.value, EmbeddingError)  # region_search's base error
