"""The region_recommender node and the embedding service's client (rospy here).

The cores (ranking, recommender, knowledge) know nothing of ROS; this module turns the node's
parameters (params.RegionRecommenderParams) into a PlaceRecommender for the embedding service's
backend, requests into calls and results into responses. The regions layer of igmm_layers is
reached only through its LocateObjects service.
Start-up contract: the recommender advertises ~recommend at once and waits for the embedding
service as long as it takes, checking every ~embedding_check_period s and logging what it waits
for every ~log_period s. Meanwhile ~recommend answers `success=False` with the embedding server's
"embedding model still loading (...)" message, or "waiting for the embedding service <name>
(...)" while no server is there. When the server goes away and comes back (a restart), the
recommender reconnects by itself and rebuilds its label vectors if the model changed.
"""
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import Point, Pose, Quaternion

from igmm_layers.srv import LocateObjects
from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords
from region_search.errors import (
    CorpusError,
    EmbeddingError,
    EmbeddingUnavailableError,
    LabelFileError,
    ModelLoadingError,
)
from region_search.labels import Region, load_descriptions, load_label_file, with_descriptions
from region_search.params import BACKENDS, RegionRecommenderParams
from region_search.progress import LOADING_PREFIX
from region_search.ranking import (
    PlaceRecommender,
    SentenceFeatures,
    WordFeatures,
    load_ranking_weights,
)
from region_search.srv import Embed, RecommendRegion, RecommendRegionResponse
from robot_common.ros_node import read_config

__all__ = ["EmbeddingClient", "RegionRecommenderNode", "start_region_recommender"]


class EmbeddingClient:
    """`embed_words` / `embed_phrases` for the recommender cores, through the embedding server's
    ~embed service (one persistent connection, re-opened after a failure). Remembers the
    backend, its fallback note and the model of the last successful answer.
    Raises EmbeddingUnavailableError when the service cannot be reached, ModelLoadingError (with
    the server's "embedding model still loading (...)" message) while its model loads, and
    EmbeddingError for any other failure."""

    def __init__(self, service: str):
        self.service = service
        self.backend = ""
        self.backend_note = ""
        self.model = ""
        self._proxy: Optional[rospy.ServiceProxy] = None
        self._lock = threading.Lock()

    def available(self, timeout: float = 0.1) -> bool:
        """Whether the service is advertised (waits at most `timeout` s)."""
        try:
            rospy.wait_for_service(self.service, timeout=timeout)
            return True
        except rospy.ROSException:
            return False

    @property
    def identity(self) -> Tuple[str, str]:
        """(backend, model) of the last answer: vectors of different identities do not mix."""
        return self.backend, self.model

    def __call__(self, words: List[str]) -> EmbeddedWords:
        with self._lock:
            try:
                if self._proxy is None:
                    self._proxy = rospy.ServiceProxy(self.service, Embed, persistent=True)
                response = self._proxy(list(words))
            except (rospy.ServiceException, rospy.ROSException, OSError) as err:
                self._proxy = None
                raise EmbeddingUnavailableError(
                    f"embedding service {self.service} not reachable: {err}") from err
            if response.success:
                self.backend, self.backend_note = response.backend, response.backend_note
                self.model = response.model
        if not response.success:
            if response.message.startswith(LOADING_PREFIX) or not response.backend:
                raise ModelLoadingError(response.message)
            raise EmbeddingError(f"embedding service {self.service}: {response.message}")
        dimension = int(response.dimension)
        vectors = np.asarray(response.vectors, dtype=np.float64).reshape(len(words), dimension)
        return EmbeddedWords(list(words), vectors, np.asarray(response.weights, dtype=np.float64),
                             list(response.notes), list(response.oov_words))

    embed_words = __call__
    embed_phrases = __call__


class RegionRecommenderNode:
    """Answers "where is <phrase>?" with ranked labelled regions.

    Parameters (params.RegionRecommenderParams; defaults in config/region_search.yaml,
    generated from it):
      ~labels_path (str, ""): map_labelling JSON label file; re-read when it changes. A label
          may carry a "description" (what a visitor's sign says about the place).
      ~descriptions_path (str, ""): optional YAML/JSON {label: description} file (for label
          files one cannot edit; its entries win); re-read when it changes.
      ~embedding_service (str, "/embedding_server/embed"): the embedding server's ~embed.
      ~embedding_check_period (float, 1.0): seconds between checks of the embedding service
          while it is missing or its model still loads; the node waits as long as it takes.
      ~log_period (float, 10.0): seconds between log lines saying what it still waits for.
      ~ranking_weights_path (str, ""): the ranking settings per backend (evidence weights,
          description offset, no-match threshold); "" = region_search/ranking_weights.yaml.
      ~answer_no_match (bool, true): answer "no labelled place matches" (no labels,
          matched=false) when the best score is below the backend's no-match threshold.
      ~layer_service (str, "/igmm_layers/locate_objects"): regions layer (class_name "any",
          layer "regions"); optional: used when it is there, never waited for. "" disables.
      ~layer_period (float, 2.0): seconds between queries of the regions layer.
      ~wordnet_dir (str, "/usr/share/wordnet"), ~use_wordnet (bool, true): place knowledge
          and label expansion from WordNet.
      ~top_k (int, 3): regions returned when a request asks for 0.
      ~frame_id (str, "map"): frame of the label positions.
    Services:
      ~recommend (region_search/RecommendRegion)
    Service clients: ~embedding_service (region_search/Embed), ~layer_service
      (igmm_layers/LocateObjects, optional).
    """

    def __init__(self, config: RegionRecommenderParams):
        self.config = config
        self.labels_path = config.labels_path
        self.descriptions_path = config.descriptions_path
        self.descriptions: Dict[str, str] = {}
        self._descriptions_stamp = None
        self.client = EmbeddingClient(config.embedding_service)
        self.layer_service = config.layer_service
        self.layer_period = config.layer_period
        self.top_k = config.top_k
        self.frame_id = config.frame_id
        self.answer_no_match = config.answer_no_match
        self.ranking_weights_path = config.ranking_weights_path  # read for the backend served
        self.wordnet = None
        if config.use_wordnet:
            try:
                self.wordnet = WordNet(config.wordnet_dir)
            except CorpusError as err:
                rospy.logwarn(f"region_recommender: labels not expanded: {err}")
        self.recommender = None  # built for the embedding service's backend (see _recommender)
        self._built_for: Tuple[str, str] = ("", "")
        self.lock = threading.Lock()
        self.file_regions: List[Region] = []
        self.layer_regions: List[Region] = []
        self.file_error = ""
        self._file_stamp = None
        self._timer = None
        self._check_timer = None
        self._service = None
        self.embedding_ready = False
        self.waiting_for = f"waiting for the embedding service {self.client.service} (not checked yet)"
        self._waiting_since = time.monotonic()
        self._last_log = 0.0

    def setup(self) -> None:
        """Serve ~recommend now; check the embedding service in the background until it answers
        (and again whenever it stops answering)."""
        self.refresh_file()
        if self.layer_service and self.layer_period > 0:
            self._timer = rospy.Timer(rospy.Duration(self.layer_period), self._poll_layer)
        self._service = rospy.Service("~recommend", RecommendRegion, self.handle_recommend)
        rospy.loginfo(f"region_recommender: ~recommend up; waiting for the embedding service "
                      f"{self.client.service} (as long as it takes)")
        self.check_embedding()
        self._check_timer = rospy.Timer(rospy.Duration(self.config.embedding_check_period),
                                        self.check_embedding)

    def check_embedding(self, _event=None) -> None:
        """Probe the embedding service while it is not known to answer; log what is waited for."""
        if self.embedding_ready:
            return
        try:
            if not self.client.available(0.05):
                raise EmbeddingUnavailableError(
                    f"waiting for the embedding service {self.client.service} (not advertised)")
            self.client(["probe"])  # learns the service's backend
        except ModelLoadingError as err:
            self._waiting(str(err))
            return
        except EmbeddingUnavailableError as err:
            self._waiting(str(err) if str(err).startswith("waiting") else
                          f"waiting for the embedding service {self.client.service} ({err})")
            return
        except EmbeddingError as err:
            self._waiting(f"waiting for the embedding service {self.client.service}: {err}")
            return
        waited = time.monotonic() - self._waiting_since
        self.embedding_ready = True
        rospy.loginfo(f"region_recommender: embedding backend {self.client.backend} "
                      f"({self.client.model}) answers after {waited:.1f} s of waiting: "
                      "ready")

    def _waiting(self, why: str) -> None:
        if self.embedding_ready or not self.waiting_for:
            self._waiting_since = time.monotonic()
        self.embedding_ready = False
        self.waiting_for = why
        now = time.monotonic()
        if self.config.log_period > 0 and now - self._last_log >= self.config.log_period:
            self._last_log = now
            rospy.loginfo(f"region_recommender: {why}; waited {now - self._waiting_since:.0f} s")

    def refresh_descriptions(self) -> None:
        """(Re-)read the description file when its modification time changed."""
        if not self.descriptions_path:
            return
        path = Path(self.descriptions_path)
        stamp = path.stat().st_mtime_ns if path.is_file() else None
        if stamp == self._descriptions_stamp:
            return
        self._descriptions_stamp = stamp
        try:
            self.descriptions = load_descriptions(path)
            rospy.loginfo(f"region_recommender: {len(self.descriptions)} label descriptions "
                          f"from {path}")
        except LabelFileError as err:
            self.descriptions = {}
            rospy.logwarn(f"region_recommender: label descriptions not used: {err}")

    def refresh_file(self) -> None:
        """(Re-)read the label file (and the description file) when they changed."""
        self.refresh_descriptions()
        if not self.labels_path:
            return
        path = Path(self.labels_path)
        stamp = path.stat().st_mtime_ns if path.is_file() else None
        if stamp == self._file_stamp:
            return
        self._file_stamp = stamp
        try:
            self.file_regions, self.file_error = load_label_file(path), ""
            rospy.loginfo(f"region_recommender: {len(self.file_regions)} labels from {path}")
        except LabelFileError as err:
            self.file_regions, self.file_error = [], str(err)
            rospy.logwarn(f"region_recommender: {err}")

    def _poll_layer(self, _event=None) -> None:
        try:
            rospy.wait_for_service(self.layer_service, timeout=0.05)
            response = rospy.ServiceProxy(self.layer_service, LocateObjects)(
                class_name="any", region_id="", layer="regions")
        except (rospy.ROSException, rospy.ServiceException, OSError):
            return  # optional: the layer server is not (yet) there
        if response.success:
            self.layer_regions = [Region(c.class_name, c.mean.x, c.mean.y, c.mean.z,
                                         source="regions_layer") for c in response.clusters]

    def handle_recommend(self, request) -> RecommendRegionResponse:
        with self.lock:
            self.refresh_file()
            regions = with_descriptions(self.file_regions + self.layer_regions,
                                        self.descriptions)
            if not regions:
                why = self.file_error or (f"label file {self.labels_path!r} missing" if
                                          self.labels_path else "no label file configured")
                return RecommendRegionResponse(
                    success=False, message=f"no labelled regions known ({why}; regions layer "
                    f"{self.layer_service or 'disabled'} gave none)", frame_id=self.frame_id)
            top_k = int(request.top_k) or self.top_k
            try:
                try:
                    result = self._recommend(regions, request.phrase, top_k)
                except EmbeddingUnavailableError:
                    # e.g. the server restarted: the old connection is gone; one new attempt
                    if not self.client.available(0.5):
                        raise
                    result = self._recommend(regions, request.phrase, top_k)
            except (ModelLoadingError, EmbeddingUnavailableError) as err:
                self._waiting(str(err) if isinstance(err, ModelLoadingError) else
                              f"waiting for the embedding service {self.client.service} ({err})")
                return RecommendRegionResponse(
                    success=False, message=self.waiting_for, frame_id=self.frame_id,
                    backend=self.client.backend, backend_note=self.client.backend_note)
            except EmbeddingError as err:
                return RecommendRegionResponse(
                    success=False, message=str(err), frame_id=self.frame_id,
                    backend=self.client.backend, backend_note=self.client.backend_note)
            if not self.embedding_ready:
                self.check_embedding()
        if result.matched:
            best = result.results[0]
            places = len(self.recommender.regions)
            message = (f"best: {best.region.name} ({best.score:.2f}) of {places} places "
                       f"({self.client.backend} backend)")
            if not result.sure:
                message = (f"not sure (confidence {result.confidence:.2f}, below "
                           f"{self.recommender.weights.sure_confidence:.2f}): {message}")
        else:
            closest = result.closest[0]
            message = (f"no labelled place matches {request.phrase!r} (closest: "
                       f"{closest.region.name}, score {closest.score:.2f}, does not stand out "
                       f"from the other labels by the no-match margin "
                       f"{self.recommender.weights.no_match_margin:.2f})")
        if result.fallbacks:
            message += "; fallbacks: " + "; ".join(result.fallbacks)
        if self.client.backend_note:
            message += f"; {self.client.backend_note}"
        return RecommendRegionResponse(
            success=True, message=message, labels=[r.region.name for r in result.results],
            scores=[r.score for r in result.results],
            poses=[Pose(Point(r.region.x, r.region.y, r.region.z), Quaternion(*r.region.orientation))
                   for r in result.results],
            frame_id=self.frame_id, sources=[r.region.source for r in result.results],
            explanations=[r.explanation for r in result.results], oov_words=result.oov_words,
            fallbacks=result.fallbacks, backend=self.client.backend,
            backend_note=self.client.backend_note, matched=result.matched,
            confidence=result.confidence)

    def _recommender(self):
        """The recommender for the service's current backend and model (rebuilt on a change:
        vectors of two models must not mix, e.g. after the server restarted with a fallback).
        While the backend is not known yet, one small request learns it first: features built
        for a guessed backend would encode every label only to be thrown away."""
        if not self.client.backend:
            self.client(["probe"])
        if self.recommender is None or self._built_for != self.client.identity:
            identity = self.client.identity
            backend = self.client.backend if self.client.backend in BACKENDS else "word2vec"
            weights = load_ranking_weights(backend, self.ranking_weights_path)  # LabelFileError
            if not self.answer_no_match:
                weights = replace(weights, no_match_margin=float("-inf"))
            features = (WordFeatures(self.client, self.wordnet) if backend == "word2vec"
                        else SentenceFeatures(self.client, self.wordnet))
            self.recommender = PlaceRecommender(features, weights)
            self._built_for = identity
        return self.recommender

    def _recommend(self, regions: List[Region], phrase: str, top_k: int):
        for _ in range(3):
            recommender = self._recommender()
            built_for = self._built_for
            recommender.set_regions(regions)
            result = recommender.recommend(phrase, top_k)
            if self.client.identity == built_for:
                return result
        raise EmbeddingError(f"the embedding service {self.client.service} keeps changing its "
                             "model; try again")


def start_region_recommender() -> RegionRecommenderNode:
    """The region_recommender node: parameters read, ~recommend advertised."""
    node = RegionRecommenderNode(read_config(RegionRecommenderParams))
    node.setup()
    return node
