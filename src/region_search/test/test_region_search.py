"""Region search through ROS: the real embedding_server and region_recommender nodes (launched
with launch/region_search.launch), a label file of the generated building, and the real
igmm_layers layer server's regions layer (reached through its LocateObjects service).

The default backend (the sentence model all-MiniLM-L6-v2) is checked on clear cases; its fallback
to word2vec is produced for real (a model folder that holds no model). The word2vec tests serve a
small hand-made word2vec text file (backend word2vec, a "pretrained" model), so the expected
answers are known without training; the full models belong to bench/ and the demo.
"""

import numpy as np
import pytest
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from region_search.srv import Embed, PhraseSimilarity, RecommendRegion
from robot_common.msg import ObjectObservation
from robot_sim.building import generate_building
from ros_harness import wait_until

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


def start_region_search(roslaunch, rospy_node, files, **args):
    """region_search.launch serving the hand-made word2vec space (unless `args` say otherwise);
    the no-match margin belongs to real models' scores, so these always rank."""
    settings = dict(backend="word2vec", source="pretrained",
                    pretrained_path=str(files / "vectors.txt"), cache_dir=str(files / "cache"),
                    remove_components=-1, answer_no_match="false")
    settings.update(args)
    launch = roslaunch("region_search", "region_search.launch", **settings)
    launch.wait_for_services(SERVICES, timeout=90)
    wait_for_model(rospy_node, 120)
    return launch


def test_phrases_find_their_labelled_regions_with_positions(roslaunch, rospy_node, files, building):
    start_region_search(roslaunch, rospy_node, files, labels_path=str(files / "labels.json"),
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


def test_empty_phrase_and_missing_labels_get_success_false(roslaunch, rospy_node, files):
    start_region_search(roslaunch, rospy_node, files, labels_path=str(files / "no_such_labels.json"),
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


def test_regions_layer_of_the_layer_server_is_searched_too(roslaunch, rospy_node, files):
    """The labelled places come from the real layer server (no label file): place observations
    of "water_fountain" are learnt by its regions layer and found by the recommender."""
    layer = roslaunch("igmm_layers", "igmm_layers.launch")  # the layer server's shipped defaults
    layer.wait_for_services(["/igmm_layers/locate_objects"], timeout=60)
    start_region_search(roslaunch, rospy_node, files, labels_path="")
    publisher = rospy_node.Publisher("/igmm_layers/place_observations", ObjectObservation,
                                     queue_size=100)
    wait_until(lambda: publisher.get_num_connections() > 0, 30, what="layer server subscription")
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


def test_the_default_sentence_backend_ranks_phrases_through_the_services(roslaunch, rospy_node,
                                                                         files, building):
    """Defaults of region_search.launch: the sentence model and the shipped phrase-level ranking
    (the generated building's places found, best first, room numbers matched)."""
    launch = roslaunch("region_search", "region_search.launch", labels_path=str(files / "labels.json"),
                       layer_service="")
    launch.wait_for_services(SERVICES, timeout=120)
    wait_for_model(rospy_node, 300)
    assert rospy_node.get_param("/embedding_server/active_backend") == "sentence"
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)
    for phrase, best in [("where can I get a drink of water", "water_fountain"),
                         ("restroom", "bathroom"), ("take the lift", "elevator"),
                         ("microscope", "bio_lab"), ("office 202", "office_202"),
                         ("classroom 101", "classroom_101")]:
        response = recommend(phrase=phrase, top_k=3)
        assert response.success, response.message
        assert response.labels[0] == best, (phrase, response)
        assert list(response.scores) == sorted(response.scores, reverse=True), response
        pose = response.poses[0]
        assert (pose.position.x, pose.position.y) == pytest.approx(building.labels[best], abs=1e-3)
        assert response.backend == "sentence" and response.backend_note == ""
        assert "(sentence backend)" in response.message
        assert response.matched and response.explanations[0].startswith("evidence: name ")
    assert "number_match 1.00" in recommend(phrase="classroom 101", top_k=3).explanations[0]
    typo = recommend(phrase="the printerz room", top_k=1)
    assert typo.labels[0] == "printer_room" and list(typo.oov_words) == ["printerz"]
    assert "word pieces 'printer' + '##z'" in typo.fallbacks[0]
    empty = recommend(phrase=" ", top_k=1)
    assert not empty.success and "has no words" in empty.message
    # A place the building has no label for (it has no garage): never a confident answer; either
    # "no labelled place matches" or the ranked places as a best guess, "not sure"
    nothing = recommend(phrase="the parking garage", top_k=3)
    assert nothing.success and nothing.confidence < 0.5, nothing
    if nothing.matched:
        assert nothing.message.startswith("not sure (confidence ") and len(nothing.labels) == 3
    else:
        assert list(nothing.labels) == [] and nothing.message.startswith(
            "no labelled place matches 'the parking garage' (closest: ")
    sure = recommend(phrase="take the lift", top_k=3)
    assert sure.confidence > nothing.confidence and not sure.message.startswith("not sure")
    embed = rospy_node.ServiceProxy("/embedding_server/embed", Embed)(
        phrases=["water fountain", "drinking fountain", "elevator"])
    assert embed.success and embed.dimension == 384 and embed.backend == "sentence"
    vectors = np.array(embed.vectors).reshape(3, 384)
    assert np.allclose(np.linalg.norm(vectors, axis=1), 1.0, atol=1e-4)
    assert vectors[0] @ vectors[1] > vectors[0] @ vectors[2]
    assert embed.model.startswith("sentence model all-MiniLM-L6-v2")
    similarity = rospy_node.ServiceProxy("/embedding_server/similarity", PhraseSimilarity)
    candidates = ["kitchen", "printer room", "water fountain", "elevator"]
    scored = similarity(phrase="print a poster", candidates=candidates, method="")
    assert scored.success and candidates[int(np.argmax(scored.scores))] == "printer room"


def test_a_missing_sentence_model_falls_back_to_static_vectors_or_stops_with_a_clear_error(
        roslaunch, rospy_node, files, tmp_path):
    """~model_path names a folder without a model: with ~fallback (default) the server serves
    the static phrase vectors and says so everywhere; without, a second server exits with the
    reason."""
    no_model = tmp_path / "no_model"
    no_model.mkdir()
    strict = roslaunch.node("region_search", "embedding_server", name="strict_embedding_server",
                            params={"model_path": str(no_model), "fallback": False})
    launch = start_region_search(roslaunch, rospy_node, files, backend="sentence", model_path=str(no_model),
                                 labels_path=str(files / "labels.json"), layer_service="")
    assert rospy_node.get_param("/embedding_server/active_backend") == "static"
    embed = rospy_node.ServiceProxy("/embedding_server/embed", Embed)(phrases=["water fountain"])
    assert embed.success and embed.backend == "static" and embed.dimension == 256
    assert embed.backend_note == ("fallback to static: sentence model unavailable: "
                                  f"{no_model} holds no sentence-transformers model "
                                  "(no modules.json or config.json)")
    assert embed.backend_note in embed.message
    recommend = rospy_node.ServiceProxy("/region_recommender/recommend", RecommendRegion)
    response = recommend(phrase="drinking fountain", top_k=1)
    assert response.success and list(response.labels) == ["water_fountain"]
    assert response.backend == "static" and response.backend_note == embed.backend_note
    assert "(static backend)" in response.message
    assert embed.backend_note in response.message
    wait_until(lambda: "fallback to static: sentence model unavailable" in launch.log_tail(200),
               30, what="the fallback warning in the embedding server's log")
    # Without fallback: the node exits with the reason (roslaunch reports the death).
    wait_until(lambda: "strict_embedding_server-1] process has died" in strict.log_tail(200), 60,
               what="the strict embedding server to exit")
    log = strict.log_tail(200)
    assert (f"embedding_server: sentence model unavailable (fallback disabled): {no_model} holds "
            "no sentence-transformers model") in log
    assert "exit code 1" in log
    assert not rospy_node.has_param("/strict_embedding_server/active_backend")


def test_label_descriptions_from_the_label_file_and_a_descriptions_file(roslaunch, rospy_node,
                                                                         files):
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
    start_region_search(roslaunch, rospy_node, files, labels_path=str(labels),
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
