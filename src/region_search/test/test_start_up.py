"""No service error at any moment of start-up, through ROS.

A client asks the real region_recommender for a place every 0.2 s from the moment it is
launched, alone, before any embedding server runs; then the real embedding server is launched
and loads its model, and the client keeps asking until it has had answers for a while. Every
answer must be a result or a "not ready" answer (`success: false`, "waiting for the embedding
service ..." / "embedding model still loading ..."); no request may fail with a service error.

The moment that used to fail is a request arriving while the backend becomes ready (the label
set was taken before its vectors were, so the first evidence lookup raised a KeyError). The
recommender's own background probe would sometimes notice readiness first and hide it, so
here it runs only every 600 s (`~embedding_check_period`): the requests meet the moment of
readiness themselves, every run. Backends: word2vec serving a small hand-made vector file
(ready at once), and the default sentence model (seconds of loading).

The sentence server started here is the default one (embedding_server.launch's defaults, as
region_search.launch includes it; the recommender's parameters are the defaults that
config/region_search.yaml holds): once it is ready, the same nodes are checked for the default
backend's answers (a model load costs seconds, so it is loaded once for both). Last, a model
folder without a model: the fallback to the static vectors, or a clear exit without fallback.
"""
import threading

import numpy as np
import pytest

from region_search.srv import Embed, PhraseSimilarity, RecommendRegion
from robot_sim.building import generate_building
from ros_harness import wait_until

pytestmark = pytest.mark.ros

RECOMMEND = "/region_recommender/recommend"
NOT_READY = ("waiting for the embedding service /embedding_server/embed",
             "embedding model still loading")
PHRASES = ["drinking fountain", "wash my hands", "print a poster", "the lift", "a snack"]
WORDS = ["water", "fountain", "drinking", "wash", "hands", "bathroom", "print", "printer",
         "poster", "elevator", "lift", "kitchen", "snack", "room"]


class Asker(threading.Thread):
    """Calls ~recommend every `period` s once it is advertised; keeps every answer or error."""

    def __init__(self, rospy_node, period: float = 0.2):
        super().__init__(daemon=True)
        self.rospy, self.period = rospy_node, period
        self.answers, self.errors = [], []
        self.stopped = threading.Event()
        self.lock = threading.Lock()

    def run(self):
        proxy = self.rospy.ServiceProxy(RECOMMEND, RecommendRegion)
        advertised, count = False, 0
        while not self.stopped.is_set():
            if not advertised:
                try:
                    self.rospy.wait_for_service(RECOMMEND, timeout=self.period)
                    advertised = True
                except self.rospy.ROSException:
                    continue
            phrase = PHRASES[count % len(PHRASES)]
            count += 1
            try:
                response = proxy(phrase=phrase, top_k=3)
                with self.lock:
                    self.answers.append((phrase, response))
            except self.rospy.ServiceException as err:  # "error processing request: ..."
                with self.lock:
                    self.errors.append((phrase, str(err)))
            self.stopped.wait(self.period)

    def count(self, results: bool) -> int:
        with self.lock:
            return sum(r.success == results for _, r in self.answers)

    def not_ready_seen(self, prefix: str) -> bool:
        with self.lock:
            return any(not r.success and r.message.startswith(prefix) for _, r in self.answers)


def write_vectors(path):
    rng = np.random.default_rng(0)
    vectors = np.eye(len(WORDS)) + 0.1 * rng.random((len(WORDS), len(WORDS)))
    lines = [f"{len(WORDS)} {len(WORDS)}"] + [
        word + " " + " ".join(f"{v:.5f}" for v in row) for word, row in zip(WORDS, vectors)]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.timeout(900)
@pytest.mark.parametrize("backend", ["word2vec", "sentence"])
def test_every_answer_from_launch_through_readiness_is_a_result_or_not_ready(
        roslaunch, rospy_node, tmp_path, backend):
    building = generate_building(0)
    labels = tmp_path / "labels.json"
    labels.write_text(building.labels_json())
    asker = Asker(rospy_node)
    asker.start()
    try:
        roslaunch.node("region_search", "region_recommender", name="region_recommender",
                       params={"labels_path": str(labels), "layer_service": "",
                               "embedding_check_period": 600.0})
        wait_until(lambda: asker.count(results=False) >= 3, 120,
                   what="'waiting for the embedding service' answers before any server runs")
        if backend == "word2vec":
            write_vectors(tmp_path / "vectors.txt")
            roslaunch("region_search", "embedding_server.launch", backend="word2vec",
                      source="pretrained", pretrained_path=str(tmp_path / "vectors.txt"),
                      cache_dir=str(tmp_path / "cache"), remove_components=-1)
        else:
            roslaunch("region_search", "embedding_server.launch")
        wait_until(lambda: asker.count(results=True) >= 10 or asker.errors, 600, interval=0.5,
                   what="ten answers with results after the embedding server became ready")
    finally:
        asker.stopped.set()
        asker.join(timeout=30)
    assert asker.errors == [], asker.errors[:3]
    assert asker.not_ready_seen(NOT_READY[0])
    first_result = next(i for i, (_, r) in enumerate(asker.answers) if r.success)
    for index, (phrase, response) in enumerate(asker.answers):
        if response.success:
            assert response.labels or not response.matched, (phrase, response)
            assert len(set(response.labels)) == len(response.labels)
            assert response.backend == backend
        else:
            assert index < first_result, (phrase, response.message)  # answering from then on
            assert response.message.startswith(NOT_READY), (phrase, response.message)
    if backend == "sentence":
        check_the_default_sentence_backend(rospy_node, building)


def check_the_default_sentence_backend(rospy_node, building):
    """The sentence model and the shipped phrase-level ranking through the services (the
    generated building's places found, best first, room numbers matched)."""
    wait_until(lambda: rospy_node.has_param("/embedding_server/active_backend"), 60,
               what="the embedding server's ~active_backend")
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
        roslaunch, rospy_node, tmp_path):
    """~model_path names a folder without a model: with ~fallback (default) the server serves
    the static phrase vectors and says so everywhere; without, a second server exits with the
    reason. region_search.launch with its default backend (sentence); the recommender always
    ranks here (~answer_no_match false: the subject is the fallback, not the no-match margin)."""
    labels = tmp_path / "labels.json"
    labels.write_text(generate_building(0).labels_json())
    write_vectors(tmp_path / "vectors.txt")  # the word2vec settings of a second fallback
    no_model = tmp_path / "no_model"
    no_model.mkdir()
    strict = roslaunch.node("region_search", "embedding_server", name="strict_embedding_server",
                            params={"model_path": str(no_model), "fallback": False})
    launch = roslaunch("region_search", "region_search.launch", model_path=str(no_model),
                       source="pretrained", pretrained_path=str(tmp_path / "vectors.txt"),
                       cache_dir=str(tmp_path / "cache"), remove_components=-1,
                       answer_no_match="false", labels_path=str(labels), layer_service="")
    launch.wait_for_services(["/embedding_server/embed", "/embedding_server/similarity", RECOMMEND],
                             timeout=90)
    wait_until(lambda: rospy_node.has_param("/embedding_server/active_backend"), 120,
               interval=0.25, what="the embedding server's model to be ready (~active_backend set)")
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
