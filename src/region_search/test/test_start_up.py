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
"""
import threading

import numpy as np
import pytest

from region_search.srv import RecommendRegion
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
    labels = tmp_path / "labels.json"
    labels.write_text(generate_building(0).labels_json())
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
