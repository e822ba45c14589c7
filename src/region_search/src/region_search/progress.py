"""How far the loading of an embedding model has got (pure Python, thread-safe; no rospy).

`LoadProgress` is filled in by the loader (training.cached_word2vec, backends.load_backend) in one
thread and read by the embedding server's service handlers and diagnostics in others:

- stage: "starting", "loading the sentence model", "reading the corpus", "training word2vec",
  "loading the cached vectors", "ready" or "failed".
- While word2vec trains: epochs done of epochs total, and an estimate of the whole training time
  ("about M s"): before the first epoch ends it is the corpus size times
  `PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS` (measured on the development machine, see the README),
  afterwards the measured time per epoch times the epochs.
- `describe()`: "trained for 42 s of about 128 s (epoch 5/15)", "reading the corpus for 3 s", ...;
  the embedding server answers "embedding model still loading (<describe()>)" until it is ready.
"""
import threading
import time
from typing import Dict, Optional

__all__ = ["LoadProgress", "PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS", "LOADING_PREFIX"]

# The start of the embedding server's answer while its model loads (the recommender relays it).
LOADING_PREFIX = "embedding model still loading"

# Skip-gram word2vec, 100 dimensions, window 5, negative 5, one worker: seconds per million
# corpus tokens per epoch: 212 s of CPU for 1.77 M tokens x 15 epochs (WordNet glosses) on the
# development machine, i.e. the wall time when the process has a core to itself (see README).
PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS = 8.0


class LoadProgress:
    """The loader's progress, shared between the loading thread and the readers."""

    def __init__(self, clock=time.monotonic):
        self._clock = clock
        self._lock = threading.Lock()
        self.started = clock()
        self.stage = "starting"
        self._stage_started = self.started
        self.error = ""
        self.epochs_total = 0
        self.epochs_done = 0
        self.tokens = 0
        self._train_started: Optional[float] = None
        self._epoch_seconds: Optional[float] = None
        self.train_seconds: Optional[float] = None

    def set_stage(self, stage: str) -> None:
        with self._lock:
            self.stage = stage
            self._stage_started = self._clock()

    def training_started(self, epochs: int, tokens: int) -> None:
        with self._lock:
            self.stage = "training word2vec"
            self._stage_started = self._train_started = self._clock()
            self.epochs_total, self.epochs_done, self.tokens = int(epochs), 0, int(tokens)

    def epoch_done(self) -> None:
        with self._lock:
            self.epochs_done += 1
            if self._train_started is not None:
                self._epoch_seconds = (self._clock() - self._train_started) / self.epochs_done

    def training_done(self) -> None:
        with self._lock:
            if self._train_started is not None:
                self.train_seconds = self._clock() - self._train_started

    def finished(self, error: str = "") -> None:
        with self._lock:
            self.stage = "failed" if error else "ready"
            self.error = error
            self._stage_started = self._clock()

    @property
    def ready(self) -> bool:
        return self.stage == "ready"

    def expected_training_seconds(self) -> Optional[float]:
        """Estimated whole training time (None when no training has started)."""
        with self._lock:
            return self._expected()

    def _expected(self) -> Optional[float]:
        if self._train_started is None:
            return None
        if self._epoch_seconds is not None:
            return self._epoch_seconds * self.epochs_total
        return self.tokens * self.epochs_total * PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS / 1e6

    def snapshot(self) -> Dict[str, object]:
        """Key figures as strings for diagnostics (stage, elapsed s, epochs, expected s)."""
        with self._lock:
            now = self._clock()
            values = {"stage": self.stage, "loading for [s]": f"{now - self.started:.1f}"}
            if self._train_started is not None:
                trained = (self.train_seconds if self.train_seconds is not None
                           else now - self._train_started)
                values.update({"trained for [s]": f"{trained:.1f}",
                               "expected training [s]": f"{self._expected():.0f}",
                               "epochs": f"{self.epochs_done}/{self.epochs_total}",
                               "corpus tokens": str(self.tokens)})
            if self.error:
                values["error"] = self.error
            return values

    def describe(self) -> str:
        """One line: what the loader is doing and for how long."""
        with self._lock:
            now = self._clock()
            if self.stage == "training word2vec" and self._train_started is not None:
                return (f"trained for {now - self._train_started:.0f} s of about "
                        f"{self._expected():.0f} s, epoch {self.epochs_done}/{self.epochs_total}")
            if self.stage == "failed":
                return f"failed: {self.error}"
            return f"{self.stage} for {now - self._stage_started:.0f} s"
