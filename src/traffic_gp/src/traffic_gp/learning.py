"""How the crowd-model node learns without making its users wait (no ROS here).

`Learner` holds the served model and the lock the node's services read it under:
  - the first rows (at least `min_rows`): the tuned baselines (`quick.BaselineForecast`, about
    a second) are served at once, and the GP's choice of settings and its fit (`TrafficGP.fit`,
    outside the lock) start in a background thread;
  - new rows are folded into the served model at once (`partial_fit` without training steps:
    the baselines are refitted on all rows, the GP's data grows; then, for a GP, online steps
    in chunks of `chunk_steps`, each holding the lock briefly), and kept for a running job;
  - a finished job's model takes in the rows that came while it ran and then replaces the
    served one (the GP with its `serving`: the baselines stay served where the held-out days
    say they forecast better, and its intervals are calibrated on those days);
  - when the rows have grown `refit_growth` times since the last job, a refit runs in the
    background with the chosen settings, its kernel and likelihood started from the served
    GP's (no candidate screening); when they have grown `reselect_growth` times since the last
    choice of settings, a whole new choice (screened on a bounded sample stratified by place
    and hour, `selection.stratified_sample`);
  - a job that fails leaves the served model in place and is tried again once the rows have
    doubled; the status says so.
"""
import logging
import threading
import time
from typing import Callable, List, Optional

import traffic_gp.gp_parts as gp_parts
from traffic_gp.model import SETTINGS, TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.posterior import PosteriorSnapshot
from traffic_gp.quick import BaselineForecast
from traffic_gp.training import COMPILE_STEPS

log = logging.getLogger(__name__)

WHAT = {"select": "choosing the GP's settings and fitting it",
        "refit": "refitting the GP with its chosen settings"}


class Job:
    """A fit running in a thread of its own; `later` keeps the rows that came meanwhile."""

    def __init__(self, kind: str, rows: int, fit: Callable[[], TrafficGP]):
        self.kind, self.rows, self.started = kind, rows, time.monotonic()
        self.later: List[Observations] = []
        self.result: Optional[TrafficGP] = None
        self.error: Optional[BaseException] = None
        self.thread = threading.Thread(target=self._run, args=(fit,), name=f"crowd-{kind}",
                                       daemon=True)
        self.thread.start()

    def _run(self, fit) -> None:
        try:
            self.result = fit()
        except Exception as err:  # noqa: BLE001 - reported by the learner, the node serves on
            self.error = err

    def done(self) -> bool:
        return not self.thread.is_alive()

    def describe(self) -> str:
        return (f"{WHAT[self.kind]} in the background on {self.rows} rows "
                f"(for {time.monotonic() - self.started:.0f} s)")


class Learner:
    """The served model and its background fits (see the module)."""

    def __init__(self, model_params: dict, *, min_rows: int, initial_steps: int,
                 refit_growth: float, reselect_growth: float, chunk_steps: int):
        self.model_params, self.min_rows, self.initial_steps = model_params, min_rows, initial_steps
        self.refit_growth, self.reselect_growth = refit_growth, reselect_growth
        self.chunk_steps = chunk_steps
        self.lock = threading.Lock()
        self.model = None
        self.job: Optional[Job] = None
        self.job_rows = 0            # rows of the last job (or of the loaded model)
        self.selection_rows = 0      # rows of the last choice of settings
        self.note = ""               # why the baselines are still served after a job

    def loaded(self, model) -> None:
        """Serve a model read from a file (its settings were chosen on its rows)."""
        self.model = model
        self.job_rows = self.selection_rows = model.n_rows_

    # ---- learning -------------------------------------------------------------------------
    def add(self, rows: Observations, cells, commit: Callable[[], None]) -> bool:
        """Fold `rows` into the served model (`commit` runs under the lock once they are in);
        False while there is no model and fewer than `min_rows` rows (the caller keeps them)."""
        if self.model is None:
            if len(rows) < self.min_rows:
                return False
            quick = BaselineForecast().fit(rows, cells)
            # the job first: no answer may see the baselines served without the GP's job
            self._start("select", rows, cells)
            with self.lock:
                self.model = quick
                commit()
            log.info("serving the baselines at once: %s", quick.status())
            return True
        if isinstance(self.model, PosteriorSnapshot):     # first new rows after loading a file
            self._make_trainable()
        if self.job is not None:
            self.job.later.append(rows)
        with self.lock:
            self.model.partial_fit(rows, n_steps=0)
            commit()
        return True

    def step(self, cells, stop: threading.Event, trained: bool, rows_coming: bool = False) -> None:
        """Swap in a finished job's model, start the jobs the growth asks for and, after new
        rows (`trained`), train the served GP a little (`online_steps`, in chunks). A model
        served from a file is made trainable here once rows are coming (a source is connected),
        so that the first rows are taken in without waiting for TensorFlow."""
        if self.job is not None and self.job.done():
            self._finish()
        if isinstance(self.model, PosteriorSnapshot) and rows_coming:
            self._make_trainable()
        if self.model is None or isinstance(self.model, PosteriorSnapshot):
            return
        if self.job is None:
            self._grow(cells)
        if not (trained and isinstance(self.model, TrafficGP)):
            return
        steps = self.model.online_steps
        for done in range(0, steps, self.chunk_steps):
            if stop.is_set():
                return
            with self.lock:
                self.model.partial_fit(Observations.empty(),
                                       n_steps=min(self.chunk_steps, steps - done))

    def _make_trainable(self) -> None:
        """Replace the served file's posterior by the trainable model of the same file (the
        same answers), loaded and made ready to train outside the lock."""
        trainable = TrafficGP.load(self.model.path)
        self._ready_to_train(trainable)
        with self.lock:
            self.model = trainable

    @staticmethod
    def _ready_to_train(model) -> None:
        """Rounds of `online_steps` steps go on for the node's life, in short chunks: a
        compiled step when a round is long enough to pay for tracing it (COMPILE_STEPS)."""
        if isinstance(model, TrafficGP) and model.online_steps >= COMPILE_STEPS:
            model.prepare_training()

    def _grow(self, cells) -> None:
        rows = self.model.n_rows_
        if isinstance(self.model, BaselineForecast):       # the GP's fit failed: try again
            if rows >= 2 * max(self.job_rows, 1):
                self._start("select", self.model.data_, cells)
        elif self.reselect_growth > 1 and rows >= self.reselect_growth * max(self.selection_rows, 1):
            self._start("select", self.model.data_, cells)
        elif self.refit_growth > 1 and rows >= self.refit_growth * max(self.job_rows, 1):
            self._start("refit", self.model.data_, cells)

    def _start(self, kind: str, rows: Observations, cells) -> None:
        params, warm = dict(self.model_params), None
        if kind == "refit":
            params.update({name: self.model.settings_[name] for name in SETTINGS})
            with self.lock:
                warm = gp_parts.parameter_values(self.model.model_)
            chosen = dict(self.model.selection_ or {})
        else:
            self.selection_rows = len(rows)

        def fit() -> TrafficGP:
            model = self._fit_gp(params, rows, cells, warm)
            self._ready_to_train(model)
            if kind == "refit" and chosen.get("reason"):
                model.selection_ = dict(chosen, reason=f"refitted on {len(rows)} rows, warm, "
                                                       f"with the settings of: {chosen['reason']}")
            return model

        self.job_rows = len(rows)
        self.job = Job(kind, len(rows), fit)
        log.info("started %s", self.job.describe())

    def _fit_gp(self, params: dict, rows: Observations, cells, warm) -> TrafficGP:
        """The background fit (runs in the job's thread)."""
        return TrafficGP(**params).fit(rows, n_steps=self.initial_steps, cells=cells,
                                       warm_start=warm)

    def _finish(self) -> None:
        job = self.job
        if job.error is not None:
            note = (f"{WHAT[job.kind]} failed ({type(job.error).__name__}: {job.error}); "
                    f"tried again once the rows have doubled")
            with self.lock:
                self.job, self.note = None, note
            log.error("traffic_gp: %s", note)
            return
        model = job.result
        if job.later:
            model.partial_fit(Observations.concat(job.later), n_steps=0)    # not served yet
        with self.lock:
            self.model, self.job, self.note = model, None, ""
        log.info("traffic_gp: the GP fitted in %.0f s now serves: %s",
                 time.monotonic() - job.started, model.status())

    # ---- what it says ---------------------------------------------------------------------
    def serving_note(self) -> str:
        """'' when the GP is served; else what is served instead and why (short)."""
        if not isinstance(self.model, BaselineForecast):
            serving = getattr(self.model, "serving_", None)
            return "" if serving is None else serving.verdict()
        if self.job is not None:
            return "serving the baselines while the GP is selected and fitted"
        return "serving the baselines only: " + (self.note or "no GP yet")

    def describe(self) -> str:
        """What the learner does now (call with the lock held)."""
        if self.model is None:
            return f"no model yet (a first fit once {self.min_rows} rows are in)"
        parts = [self.serving_note()] if self.serving_note() else []
        if self.job is not None:
            parts.append(self.job.describe())
        elif self.note and not parts:
            parts.append(self.note)
        return "; ".join(parts) or "serving the GP"
