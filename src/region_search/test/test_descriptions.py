"""Numbers said as words, label descriptions (label-file field and
sidecar file) in both ranking methods.
The expected answers are written by hand from the phrases, not recorded from the code."""
import json

import pytest

from region_search.errors import LabelFileError
from region_search.labels import Region, load_descriptions, load_label_file, with_descriptions
from region_search.text_similarity import spoken_numbers
from region_search.word_matching import WordMatcher


@pytest.mark.parametrize("said, written", [
    ("room three eleven", "room 311"),
    ("three one one", "311"),
    ("Three Twenty-One", "321"),
    ("three twenty one please", "321 please"),
    ("room three hundred and eleven", "room 311"),
    ("room number three hundred twenty one", "room number 321"),
    ("go to three-two-one", "go to 321"),
    ("three twentyone", "321"),
    ("two hundred", "200"),
    ("four oh four", "404"), ("room three oh four", "room 304"),  # "oh": a zero inside
    ("oh no", "oh no"),
    ("one of the labs", "one of the labs"),   # a single number word stays a word
    ("twenty", "twenty"),
    ("two and three", "two and three"),   # "and" only inside "... hundred and ..."
    ("room 311", "room 311"),
    ("the third floor", "the third floor"),
])
def test_spoken_numbers_become_digits(said, written):
    assert spoken_numbers(said) == written


def test_descriptions_come_from_the_label_file_and_from_a_sidecar_file(tmp_path):
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({
        "grasp": {"x": 1, "y": 2, "description": "the GRASP   robotics\nlaboratory"},
        "bio_lab": {"x": 3, "y": 4}}))
    regions = {r.name: r for r in load_label_file(labels)}
    assert regions["grasp"].description == "the GRASP robotics laboratory"
    assert regions["bio_lab"].description == ""
    sidecar = tmp_path / "descriptions.yaml"
    sidecar.write_text("bio_lab: the biology laboratory\ngrasp: robots\n")
    described = {r.name: r for r in with_descriptions(list(regions.values()),
                                                      load_descriptions(sidecar))}
    assert described["bio_lab"].description == "the biology laboratory"
    assert described["grasp"].description == "robots"  # the sidecar's entry wins
    assert (described["grasp"].x, described["grasp"].y) == (1.0, 2.0)
    as_json = tmp_path / "descriptions.json"
    as_json.write_text('{"bio_lab": "wet lab"}')
    assert load_descriptions(as_json) == {"bio_lab": "wet lab"}


@pytest.mark.parametrize("content, says", [
    ("- a\n- b\n", "expected a mapping"),
    ("grasp: [1, 2]\n", "is not label: description text"),
    ("grasp: {x: 1\n", "not valid YAML/JSON"),
])
def test_bad_description_files_are_clear_errors(tmp_path, content, says):
    path = tmp_path / "descriptions.yaml"
    path.write_text(content)
    with pytest.raises(LabelFileError, match=says):
        load_descriptions(path)
    with pytest.raises(LabelFileError, match="cannot read description file"):
        load_descriptions(tmp_path / "missing.yaml")
    labels = tmp_path / "labels.json"
    labels.write_text('{"grasp": {"x": 1, "y": 2, "description": 7}}')
    with pytest.raises(LabelFileError, match="description that is not a string"):
        load_label_file(labels)


def test_word_method_matches_description_words_and_follows_a_changed_description():
    # No vectors, no WordNet: only equal words and spelling, so the description is all that
    # tells the two labs apart.
    recommender = WordMatcher(None, hubness=False)
    plain = [Region("lab_a", 0, 0), Region("lab_b", 1, 1)]
    recommender.set_regions(plain)
    tie = {r.region.name: r.score for r in recommender.recommend("robotics laboratory", 0).results}
    assert tie["lab_a"] == tie["lab_b"]
    described = [Region("lab_a", 0, 0, description="chemistry laboratory"),
                 Region("lab_b", 1, 1, description="the robotics laboratory")]
    recommender.set_regions(described)
    assert recommender.recommend("robotics laboratory", 1).results[0].region.name == "lab_b"
    assert recommender.recommend("chemistry", 1).results[0].region.name == "lab_a"
    swapped = [Region("lab_a", 0, 0, description="the robotics laboratory"),
               Region("lab_b", 1, 1, description="chemistry laboratory")]
    recommender.set_regions(swapped)
    assert recommender.recommend("robotics laboratory", 1).results[0].region.name == "lab_a"


def test_word_method_reads_room_numbers_said_as_words():
    rooms = [Region("towne_311", 0, 0), Region("towne_321", 1, 1), Region("towne_313", 2, 2)]
    for number_words, expected in ((True, "towne_321"), (False, None)):
        recommender = WordMatcher(None, number_words=number_words)
        recommender.set_regions(rooms)
        results = recommender.recommend("room three twenty-one", 0).results
        if expected:
            assert results[0].region.name == expected and results[0].score > results[1].score
        else:  # as words, nothing matches any room better than the others
            assert len({round(r.score, 9) for r in results}) == 1
