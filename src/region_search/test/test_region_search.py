"""Region search through ROS: the real embedding_server and region_recommender nodes (launched
with launch/region_search.launch), a label file of the generated building, and the real
igmm_layers layer server's regions layer (reached through its LocateObjects service).

These tests serve a small hand-made word2vec text file (backend word2vec, a "pretrained" model),
so the expected answers are known without training; the full models belong to bench/ and the
demo. One embedding server (embedding_server.launch) serves that file to the whole module; each
test starts its own recommender (region_search.launch without its embedding server). The default
backend (the sentence model all-MiniLM-L6-v2) and its fallback when the model is missing are
checked in test_start_up.py, where a sentence server starts anyway.
"""

import numpy as np
import pytest
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from region_search.srv import Embed, PhraseSimilarity, RecommendRegion
from robot_common.msg import ObjectObservation
from robot_sim.building import generate_building
from ros_harness import LaunchSet, wait_for_subscriber, wait_until

pytestmark = pytest.mark.ros

# Axes: drink, paper, motion, body, food, learning, work, rest.
AXES = {
    "water": "drink", "fountain": "drink", "drinking": "drink", "coffee": "food",
    "kitchen": "food", "fridge": "food", "print": "paper", "printer": "paper", "poster": "paper",
    "elevator": "motion", "lift": "motion", "bathroom": "body",
    "toilet": "body", "wash": "body", "hands": "body", "classroom": "learning", "bio": "learning",
    "lab": "learning", "conference": "work", "office": "work", "lounge": "rest", "nap": "rest",
    "vending": "food", "machines": "food", "snack": "food",
}
DIMENSIONS = ["drink", "paper", "motion", "body", "food", "learning", "work", "rest"]


def write_vectors(path):
    rng = np.random.default_rng(0)
    lines = [f"{len(AXES) + 1} {len(DIMENSIONS)}"]
    for word, axis in list(AXES.items()) + [("room", None)]:
        vector = 0.1 * rng.random(len(DIMENSIONS))
        if axis:
            vector[DIMENSIONS.index(axis)] = 1.0
        lines.append(word + " " + " ".join(f"{v:.5f}" for v in vector))
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def building():
    return generate_building(0)


@pytest.fixture(scope="module")
def files(tmp_path_factory, building):
    folder = tmp_path_factory.mktemp("region_search")
    write_vectors(folder / "vectors.txt")
    (folder / "labels.json").write_text(building.labels_json())
    return folder


SERVICES = ["/embedding_server/embed", "/embedding_server/similarity",
            "/region_recommender/recommend"]


def wait_for_model(rospy_node, timeout):
    """The services are advertised at once; the model is ready when ~active_backend is set."""
    wait_until(lambda: rospy_node.has_param("/embedding_server/active_backend"), timeout,
               interval=0.25, what="the embedding server's model to be ready (~active_backend set)")


@pytest.fixture(scope="module")
def word2vec_server(roscore, rospy_node, files, tmp_path_factory):
    """The embedding server serving the hand-made word2vec space, one for the module's tests."""
    launches = LaunchSet(roscore, tmp_path_factory.mktemp("word2vec_server"))
    launch = launches("region_search", "embedding_server.launch", backend="word2vec",
                      source="pretrained", pretrained_path=str(files / "vectors.txt"),
                      cache_dir=str(files / "cache"), remove_components=-1)
    launch.wait_for_services(SERVICES[:2], timeout=90)
    wait_for_model(rospy_node, 120)
    yield launch
    launches.stop_all()


def start_region_search(roslaunch, word2vec_server, **args):
    """region_search.launch's recommender on the module's word2vec server; the no-match margin
    belongs to real models' scores, so these always rank."""
    launch = roslaunch("region_search", "region_search.launch", start_embedding_server="false",
                       answer_no_match="false", **args)
    launch.wait_for_services(SERVICES, timeout=90)
    assert word2vec_server.process.alive, word2vec_server.log_tail()
    return launch


def test_phrases_find_their_labelled_regions_with_positions(roslaunch, rospy_node, files, building,
                                                           word2vec_server):
    start_region_search(roslaunch, word2vec_server, labels_path=str(files / "labels.json"),
                        layer_service="")
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)
    for phrase, best in [("drinking fountain", "water_fountain"), ("wash my hands", "bathroom"),
                         ("somewhere to print a poster", "printer_room"),
                         ("classroom 102", "classroom_102"), ("the lift", "elevator")]:
        response = recommend(phrase=phrase, top_k=2)
        assert response.success, response.message
        assert list(response.labels)[0] == best, (phrase, response)
        assert len(response.labels) == len(response.scores) == len(response.poses) == 2
        assert response.scores[0] >= response.scores[1]
        pose = response.poses[0]
        assert (pose.position.x, pose.position.y) == pytest.approx(building.labels[best], abs=1e-3)
        assert pose.orientation.w == 1.0 and response.frame_id == "map"
        assert list(response.sources) == ["label_file"] * 2
        assert response.backend == "word2vec" and response.backend_note == ""
        assert "(word2vec backend)" in response.message
    default = recommend(phrase="printerz", top_k=0)
    assert default.success and len(default.labels) == 3  # ~top_k of config/region_search.yaml
    assert default.labels[0] == "printer_room"
    assert list(default.oov_words) == ["printerz"]
    assert "spelled most alike 'printer'" in default.fallbacks[0]
    assert "fallbacks" in default.message
    check_embedding_server_answers_vectors_and_batch_similarity(rospy_node)


def check_embedding_server_answers_vectors_and_batch_similarity(rospy_node):
    """The word2vec embedding server's ~embed and ~similarity (on the same launch)."""
    embed = rospy_node.ServiceProxy("/embedding_server/embed", Embed)
    response = embed(phrases=["water fountain", "towne_321"])
    assert response.success and response.dimension == len(DIMENSIONS)
    vectors = np.array(response.vectors).reshape(2, len(DIMENSIONS))
    assert np.argmax(vectors[0]) == DIMENSIONS.index("drink")
    assert np.allclose(vectors[1], 0.0)  # neither "towne" nor a number has a vector here
    assert set(response.oov_words) == {"towne", "321"} and response.notes[0] == ""
    assert response.backend == "word2vec" and response.backend_note == ""
    empty = embed(phrases=["water", ""])
    assert not empty.success and "phrase 1" in empty.message
    similarity = rospy_node.ServiceProxy("/embedding_server/similarity", PhraseSimilarity)
    candidates = ["kitchen", "printer room", "elevator", "water fountain"]
    for method in ("", "mean", "align"):
        scored = similarity(phrase="drinking water", candidates=candidates, method=method)
        assert scored.success and len(scored.scores) == len(candidates)
        assert candidates[int(np.argmax(scored.scores))] == "water fountain"
    bad = similarity(phrase="water", candidates=["kitchen"], method="nearest")
    assert not bad.success and "unknown similarity method" in bad.message


def test_empty_phrase_and_missing_labels_get_success_false(roslaunch, rospy_node, files,
                                                           word2vec_server):
    start_region_search(roslaunch, word2vec_server, labels_path=str(files / "no_such_labels.json"),
                        layer_service="")
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)
    response = recommend(phrase="drinking fountain", top_k=1)
    assert not response.success and "no_such_labels.json' missing" in response.message
    # The label file appears later (map_publisher writes it): it is picked up without a restart.
    (files / "no_such_labels.json").write_text('{"water_fountain": {"x": 1.5, "y": 2.5}}')
    try:
        response = recommend(phrase="drinking fountain", top_k=1)
        assert response.success and list(response.labels) == ["water_fountain"]
        for phrase in ("", "   ", "?!"):
            empty = recommend(phrase=phrase, top_k=1)
            assert not empty.success and "has no words" in empty.message
            assert list(empty.labels) == []
    finally:
        (files / "no_such_labels.json").unlink()


def test_regions_layer_of_the_layer_server_is_searched_too(roslaunch, rospy_node, word2vec_server):
    """The labelled places come from the real layer server (no label file): place observations
    of "water_fountain" are learnt by its regions layer and found by the recommender."""
    layer = roslaunch("igmm_layers", "igmm_layers.launch")  # the layer server's shipped defaults
    layer.wait_for_services(["/igmm_layers/locate_objects"], timeout=60)
    start_region_search(roslaunch, word2vec_server, labels_path="")
    publisher = rospy_node.Publisher("/igmm_layers/place_observations", ObjectObservation,
                                     queue_size=100)
    wait_for_subscriber(publisher, "/igmm_layers", 60)
    rng = np.random.default_rng(1)
    for _ in range(12):
        x, y = 3.0 + 0.05 * rng.standard_normal(), 4.0 + 0.05 * rng.standard_normal()
        publisher.publish(ObjectObservation(header=Header(frame_id="map", stamp=rospy_node.Time.now()),
                                            class_name="water_fountain", position=Point(x, y, 0.0),
                                            confidence=1.0, size=Vector3(), region_id=""))
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)

    def found():
        response = recommend(phrase="drinking fountain", top_k=1)
        return response if response.success else None

    response = wait_until(found, 60, what="the regions layer's water_fountain")
    assert list(response.labels) == ["water_fountain"]
    assert list(response.sources) == ["regions_layer"]
    assert (response.poses[0].position.x, response.poses[0].position.y) == pytest.approx((3.0, 4.0), abs=0.2)


def test_label_descriptions_from_the_label_file_and_a_descriptions_file(roslaunch, rospy_node,
                                                                         files, word2vec_server):
    """Names that say nothing ("place_a"); what each place is comes from its description: a
    label file's "description" field, and ~descriptions_path (its entries win), re-read when it
    changes."""
    labels = files / "opaque_labels.json"
    labels.write_text('{"place_a": {"x": 1, "y": 1, "description": "the printer room"},'
                      ' "place_b": {"x": 2, "y": 2}, "place_c": {"x": 3, "y": 3}}')
    descriptions = files / "descriptions.yaml"
    descriptions.write_text("place_b: the kitchen\nplace_c: a lounge for a nap\n")
    # Settings for this hand-made space (~ranking_weights_path): the shipped description
    # offset is in the score units of real models; here a description counts as it is.
    weights = files / "ranking_weights.yaml"
    weights.write_text("word2vec:\n  weights: {name: 3.0, expanded: 3.0, spelling: 1.0}\n"
                       "  description_offset: 0.0\n")
    start_region_search(roslaunch, word2vec_server, labels_path=str(labels),
                        descriptions_path=str(descriptions), layer_service="",
                        ranking_weights_path=str(weights))
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)
    for phrase, best in [("print a poster", "place_a"), ("coffee", "place_b"),
                         ("take a nap", "place_c")]:
        response = recommend(phrase=phrase, top_k=3)
        assert response.success, response.message
        assert list(response.labels)[0] == best, (phrase, response)
    descriptions.write_text("place_b: a lounge for a nap\nplace_c: the kitchen\n")
    wait_until(lambda: recommend(phrase="coffee", top_k=1).labels[0] == "place_c", 30,
               what="the changed descriptions file to be used")
