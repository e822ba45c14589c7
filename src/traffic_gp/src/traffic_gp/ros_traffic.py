"""ROS side of the crowd model: PeopleCount messages in, predictions and crowd cost maps out.

`TrafficServer` is built from a `TrafficServerParams` (construction is pure); `setup()` wires ROS.
The node executable `nodes/traffic_server` only reads the parameters and calls `start`.
"""
import json
import math
import os
import queue
import shutil
import threading
import time
from typing import Any, Dict, List, NamedTuple, Optional

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import OccupancyGrid
from std_srvs.srv import Trigger, TriggerResponse

from robot_common.cells import CellGrid, visible_cells
from robot_common.errors import ConfigError
from robot_common.maps import load_map
from robot_common.msg import PeopleCount
from robot_common.ros_maps import grid_to_msg, msg_to_grid
from robot_common.ros_node import read_config
from ros_mongo.errors import StoreError
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.urls import redact_url, warn_password_in_url
from traffic_gp.errors import TrafficError
from traffic_gp.learning import Learner
from traffic_gp.observations import Observations, aggregate_view, hours_since_monday
from traffic_gp.params import TrafficServerParams
from traffic_gp.posterior import PosteriorSnapshot
from traffic_gp.queries import CrowdQueries
from traffic_gp.quick import BaselineForecast
from traffic_gp.srv import (
    PredictCount,
    PredictCountResponse,
    PredictDensity,
    PredictDensityResponse,
    PredictRegion,
    PredictRegionResponse,
)

PEOPLE_COUNT_TYPE = "robot_common/PeopleCount"
LEARNED_SUFFIX = ".learned.json"  # next to the model file: robots learned from, feed position


class FeedCount(NamedTuple):
    """A PeopleCount read from the central database: who recorded it, and the feed position."""

    msg: PeopleCount
    robot: str
    seq: Any


def learned_path(model_path: str) -> str:
    """Where the learned-from record of a model file is kept."""
    return model_path + LEARNED_SUFFIX


class TrafficServer:
    """Learns where and when people are from PeopleCount messages; serves a crowd cost map.

    Parameters (private, `TrafficServerParams`; generated config/traffic_gp.yaml):
      ~map_yaml ("": the `map` topic), ~cell_size (0.5 m), ~model_path ("": start untrained;
      else load it at start, without training, and save there), ~save_on_shutdown (false),
      ~utc_offset_hours (null / "" / "local": the machine's zone), ~clock ("ros": now is ROS
      time; "observations": the newest observation's stamp), ~dwell_time (20 s), ~min_rows
      (2000 rows before a first fit), ~initial_steps (600), ~train_period (2 s), ~chunk_steps
      (20 training steps per lock hold), ~publish_period (5 s), ~lookahead_minutes (30),
      ~lookahead_step_minutes (5), ~saturation_density (1 person/m^2 = 95), ~wall_value (-1 or
      100), ~full_resolution (true: cost maps at the map's resolution), ~frame_id ("map"),
      ~model ({}: dict of TrafficGP keyword arguments).
    Learning (`learning.Learner`): once ~min_rows rows are in, the tuned baselines are served at
      once (the status says so) while `TrafficGP.fit` (hold-out of the most recent days, the
      settings chosen on them, the baselines served where they forecast those days better,
      calibrated intervals) runs in the background; new rows are folded into what is served at
      once; the GP is refitted in the background (chosen settings, warm start) whenever the
      rows have grown ~refit_growth (2) times, its settings chosen again after
      ~reselect_growth (8) times.
      ~source ("topic": the `people_counts` topic; "central": the `_changes` feed of the central
      fleet database ~central_url, PeopleCount message documents of every robot, optionally of
      ~central_topics only), ~central_credentials_file.
    Subscribes: `map` (nav_msgs/OccupancyGrid, only when map_yaml is empty), `people_counts`
      (robot_common/PeopleCount; source topic only).
    Source central: follows the feed from its last sequence. The sequence of the last message
      folded into the model, and the rows and messages learned per robot, are saved with the
      model (`<model_path>.learned.json`) and read back with it, so a restarted node resumes
      where the saved model stopped (nothing counted twice).
    Publishes (latched): `~crowd_costmap` (maximum over now .. now + look-ahead) and
      `~crowd_costmap_now` (nav_msgs/OccupancyGrid, 0..95, walls wall_value); `/diagnostics`
      (diagnostic_msgs/DiagnosticArray, status "traffic_gp: crowd model" every publish period:
      OK serving the GP, WARN serving the baselines and why, e.g. "GP 1.00x the best baseline
      on the held-out days (needs <= 0.9x): serving the baselines").
    Services: `~predict_count` (traffic_gp/PredictCount), `~predict_region`
      (traffic_gp/PredictRegion), `~predict_density` (traffic_gp/PredictDensity: density grids
      over the model's cells at up to 48 times), `~save_model` (std_srvs/Trigger), `~status`
      (std_srvs/Trigger: which robots and how many rows and messages of each the model learned
      from, the settings the model chose and why, what it serves where, its interval
      calibration).
    """

    def __init__(self, config: TrafficServerParams):
        self.config = config
        self.cells: Optional[CellGrid] = None
        self.learner = Learner(config.model, min_rows=config.min_rows,
                               initial_steps=config.initial_steps,
                               refit_growth=config.refit_growth,
                               reselect_growth=config.reselect_growth,
                               chunk_steps=config.chunk_steps)
        self.rows_seen = 0
        self.messages_taken = 0         # PeopleCount messages taken from the inbox
        self.last_stamp = 0.0
        self._inbox = queue.Queue()     # PeopleCount messages from the subscriber thread
        self._pending: List[Observations] = []
        self._lock = self.learner.lock
        self._stop = threading.Event()
        self.learned: Dict[str, List[int]] = {}          # robot -> [rows, messages] in the model
        self._pending_learned: Dict[str, List[int]] = {}  # the same for rows not folded in yet
        self.feed_seq: Any = None                         # central feed position of the model
        self._pending_seq: Any = None
        self.follower: Optional[ChangesFollower] = None
        self._counts_sub: Optional[rospy.Subscriber] = None

    @property
    def model(self):
        """The served model (None before the first fit)."""
        return self.learner.model

    # ---- set-up -------------------------------------------------------------------------
    def setup(self) -> None:
        if self.config.map_yaml:
            self._set_map(load_map(os.path.expanduser(self.config.map_yaml)))
        else:
            rospy.Subscriber("map", OccupancyGrid, lambda msg: self._set_map(msg_to_grid(msg)),
                             queue_size=1)
        if self.config.model_path and os.path.exists(self.config.model_path):
            self._load(self.config.model_path)
            self._load_learned(learned_path(self.config.model_path))
        latch = dict(queue_size=1, latch=True)
        self.pub_window = rospy.Publisher("~crowd_costmap", OccupancyGrid, **latch)
        self.pub_now = rospy.Publisher("~crowd_costmap_now", OccupancyGrid, **latch)
        self.pub_diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)
        if self.config.source == "central":
            self._start_central()
        else:
            self._counts_sub = rospy.Subscriber("people_counts", PeopleCount, self._inbox.put,
                                                queue_size=1000)
        rospy.Service("~predict_count", PredictCount, self._predict_count)
        rospy.Service("~predict_region", PredictRegion, self._predict_region)
        rospy.Service("~predict_density", PredictDensity, self._predict_density)
        rospy.Service("~save_model", Trigger, self._save_service)
        rospy.Service("~status", Trigger, lambda _req: TriggerResponse(True, self.learned_status()))
        threading.Thread(target=self._train_loop, name="crowd-training", daemon=True).start()
        rospy.Timer(rospy.Duration(self.config.publish_period), lambda _: self.publish())
        rospy.on_shutdown(self.shutdown)

    def _load(self, path: str) -> None:
        """Serve the saved model's posterior at once (NumPy, no TensorFlow); the trainable model
        is loaded by the training thread once a source of counts is connected."""
        start = time.perf_counter()
        self.learner.loaded(PosteriorSnapshot.load(path))
        rospy.loginfo(f"traffic_gp: loaded {path} ({self.model.n_steps_} steps, "
                      f"{self.model.n_rows_} rows) in {time.perf_counter() - start:.2f} s")

    def _load_learned(self, path: str) -> None:
        """What the loaded model learned from (robots, rows, feed position), if it was saved."""
        if not os.path.exists(path):
            if self.config.source == "central":
                rospy.logwarn(f"traffic_gp: {path} is missing: following the central feed from "
                              f"its start (rows already in the model may be counted again)")
            return
        with open(path, encoding="utf-8") as stream:
            saved = json.load(stream)
        self.learned = {str(robot): [int(rows), int(count)]
                        for robot, (rows, count) in saved.get("robots", {}).items()}
        if self.config.source != "central" or saved.get("last_seq") is None:
            return
        if saved.get("central") == redact_url(self.config.central_url):
            self.feed_seq = saved["last_seq"]
        else:
            rospy.logwarn(f"traffic_gp: the saved model learned from {saved.get('central')!r}, not "
                          f"{redact_url(self.config.central_url)!r}: following the feed from its start")

    def _start_central(self) -> None:
        """Follow the central database's `_changes` feed into the inbox (a thread of its own)."""
        self.follower = self.config.central_follower(
            [PEOPLE_COUNT_TYPE], since=self.feed_seq if self.feed_seq is not None else 0)
        rospy.loginfo(f"traffic_gp: learning from {self.follower.shown} (PeopleCount documents) "
                      f"since sequence {self.follower.since}")
        threading.Thread(target=self._follow_central, name="central-changes", daemon=True).start()

    def _follow_central(self) -> None:
        while not self._stop.is_set():
            try:
                for item in self.follower.follow(self._stop):
                    try:
                        msg = item.message.message()
                    except StoreError as err:
                        rospy.logwarn_throttle(10, f"traffic_gp: skipped central document "
                                                   f"{item.message.id}: {err}")
                        continue
                    self._inbox.put(FeedCount(msg, item.message.robot_id or msg.robot_id, item.seq))
            except Exception as err:  # noqa: BLE001 - keep following; the error is reported
                rospy.logerr_throttle(30, f"traffic_gp: following {self.follower.shown} failed: "
                                          f"{type(err).__name__}: {err}")
                self._stop.wait(5.0)

    def _set_map(self, grid) -> None:
        with self._lock:
            self.cells = CellGrid.from_map(grid, self.config.cell_size)
        rospy.loginfo(f"traffic_gp: map {grid.width}x{grid.height}, {self.cells.n_cells} cells "
                      f"of {self.cells.cell_size:.2f} m")

    # ---- observations and training --------------------------------------------------------
    def to_rows(self, msg: PeopleCount) -> Observations:
        """Rows of one message (per seen cell, or one for a total count within a radius)."""
        stamp = msg.header.stamp.to_sec()
        hours = float(hours_since_monday(stamp, self.config.utc_offset_hours))
        if msg.cells:
            if not (len(msg.cells) == len(msg.seen_fraction) == len(msg.counts)):
                raise TrafficError(f"{len(msg.cells)} cells, {len(msg.seen_fraction)} fractions "
                                   f"and {len(msg.counts)} counts differ in number")
            fractions = np.asarray(msg.seen_fraction, float)
            if np.any((fractions <= 0) | (fractions > 1)):
                raise TrafficError("seen_fraction must be in (0, 1]")
            index = self.cells.index_at(np.array([p.x for p in msg.cells]),
                                        np.array([p.y for p in msg.cells]))
            ok = index >= 0
            expo = fractions[ok] * self.cells.cell_area * (1 + msg.duration / self.config.dwell_time)
            return Observations(self.cells.x[index[ok]], self.cells.y[index[ok]],
                                np.full(ok.sum(), hours), expo, np.asarray(msg.counts)[ok],
                                robot=[msg.robot_id] * int(ok.sum()))
        if not msg.radius > 0:
            raise TrafficError("a message needs cells or a positive radius")
        index, fractions = visible_cells(self.cells, msg.robot_position.x, msg.robot_position.y,
                                         msg.radius)
        return aggregate_view(self.cells, index, fractions, msg.total_count, hours,
                              duration=msg.duration, dwell_time=self.config.dwell_time,
                              robot=msg.robot_id)

    def _drain(self) -> None:
        while self.cells is not None:
            try:
                item = self._inbox.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, FeedCount):
                msg, robot = item.msg, item.robot
                self._pending_seq = item.seq
            else:
                msg, robot = item, item.robot_id
            try:
                rows = self.to_rows(msg)
            except (TrafficError, ValueError) as err:
                rospy.logwarn_throttle(10, f"traffic_gp: dropped a PeopleCount from "
                                           f"{msg.robot_id!r}: {err}")
                continue
            self.messages_taken += 1
            self._pending.append(rows)
            tally = self._pending_learned.setdefault(robot or "(no robot id)", [0, 0])
            tally[0] += len(rows)
            tally[1] += 1
            self.rows_seen += len(rows)
            self.last_stamp = max(self.last_stamp, msg.header.stamp.to_sec())

    def _train_loop(self) -> None:
        while not self._stop.wait(self.config.train_period):
            try:
                self.train_once()
            except Exception as err:  # noqa: BLE001 - keep serving; the error is reported
                rospy.logerr_throttle(30, f"traffic_gp: training failed: "
                                          f"{type(err).__name__}: {err}")

    def train_once(self) -> None:
        """Fold pending rows into the served model (the first ones once `min_rows` are in), swap
        in a finished background fit, start the fits the growth asks for (`learning.Learner`)."""
        self._drain()
        trained = False
        if self._pending:
            new = Observations.concat(self._pending)
            if self.learner.add(new, self.cells, self._commit_learned):   # raises: rows stay
                self._pending, trained = [], True
        else:
            with self._lock:
                self._commit_learned()  # messages that gave no rows still move the feed on
        self.learner.step(self.cells, self._stop, trained, rows_coming=self._rows_coming())
        if trained and self.model is not None and self.model.n_steps_:
            rospy.loginfo_throttle(30, f"traffic_gp: {self.model.n_rows_} rows, "
                                       f"{self.model.n_steps_} steps")

    def _rows_coming(self) -> bool:
        """A source of counts is there: the central feed, or a publisher of people_counts."""
        if self.follower is not None:
            return True
        return self._counts_sub is not None and self._counts_sub.get_num_connections() > 0

    def _commit_learned(self) -> None:
        """The pending rows are in the model now (call with the lock held)."""
        for robot, (rows, count) in self._pending_learned.items():
            tally = self.learned.setdefault(robot, [0, 0])
            tally[0] += rows
            tally[1] += count
        self._pending_learned = {}
        if self._pending_seq is not None:
            self.feed_seq, self._pending_seq = self._pending_seq, None

    def learned_status(self) -> str:
        """Which robots and how many rows (and messages) of each the model learned from."""
        with self._lock:
            learned = {robot: list(tally) for robot, tally in sorted(self.learned.items())}
            model_rows = self.model.n_rows_ if self.model is not None else 0
        robots = "; ".join(f"{robot}: {rows} rows from {count} messages"
                           for robot, (rows, count) in learned.items()) or "none yet"
        if self.follower is not None:
            source = f"central {self.follower.shown} at sequence {json.dumps(self.feed_seq)}"
            if self.follower.last_error:
                source += f" (last error: {self.follower.last_error})"
        else:
            source = "topic people_counts"
        with self._lock:
            chosen = self.model.status() if self.model is not None else "no model yet"
            doing = self.learner.describe()
        return (f"model of {model_rows} rows; learned from {len(learned)} robots: {robots}; "
                f"source {source}; learner: {doing}; model: {chosen}")

    # ---- answers --------------------------------------------------------------------------
    def now_hours(self, stamp=None) -> float:
        if stamp is not None and not stamp.is_zero():
            seconds = stamp.to_sec()
        elif self.config.clock == "observations" and self.last_stamp > 0:
            seconds = self.last_stamp
        else:
            seconds = rospy.Time.now().to_sec()
        return float(hours_since_monday(seconds, self.config.utc_offset_hours))

    def _queries(self) -> CrowdQueries:
        if self.cells is None:
            raise TrafficError("no map yet")
        if self.model is None:
            received = self.messages_taken + self._inbox.qsize()  # counts while a fit runs too
            raise TrafficError(f"no model yet ({self.rows_seen} observation rows so far, "
                               f"{self.config.min_rows} needed; {received} PeopleCount "
                               f"messages received)")
        return CrowdQueries(self.model, self.cells)

    def _predict_count(self, req):
        try:
            if not (math.isfinite(req.x) and math.isfinite(req.y)):
                raise TrafficError(f"x and y must be finite, got ({req.x}, {req.y})")
            with self._lock:
                est = self._queries().at(req.x, req.y, self.now_hours(req.stamp))
        except (TrafficError, ConfigError) as err:
            return PredictCountResponse(success=False, message=str(err))
        return PredictCountResponse(True, self._status(), est.expected, est.stddev, est.lower,
                                    est.upper, est.density, self.cells.cell_size)

    def _predict_region(self, req):
        polygon = [(p.x, p.y) for p in req.region.points]
        try:
            if not all(math.isfinite(v) for point in polygon for v in point):
                raise TrafficError("region vertices must be finite")
            with self._lock:
                est = self._queries().region(polygon, self.now_hours(req.stamp))
        except (TrafficError, ConfigError) as err:
            return PredictRegionResponse(success=False, message=str(err))
        return PredictRegionResponse(True, self._status(), est.expected, est.stddev, est.lower,
                                     est.upper, est.cells, est.area)

    def _predict_density(self, req):
        try:
            with self._lock:
                density, stddev = self._queries().density_grids(
                    [self.now_hours(stamp) for stamp in req.stamps or [rospy.Time(0)]])
                info = grid_to_msg(self.cells.coarse, self.config.frame_id).info
        except (TrafficError, ConfigError) as err:
            return PredictDensityResponse(success=False, message=str(err))
        return PredictDensityResponse(True, self._status(), info, density.ravel().tolist(),
                                      stddev.ravel().tolist())

    def _status(self) -> str:
        note = self.learner.serving_note()
        return (f"ok: model of {self.model.n_rows_} rows, {self.model.n_steps_} steps; "
                f"{self.rows_seen} rows received" + (f"; {note}" if note else ""))

    def publish(self) -> None:
        self.publish_diagnostics()
        if self.model is None or self.cells is None:
            return
        c = self.config
        with self._lock:
            now_grid, window_grid = self._queries().cost_grid(
                self.now_hours(), lookahead_hours=c.lookahead_minutes / 60.0,
                step_hours=c.lookahead_step_minutes / 60.0,
                saturation_density=c.saturation_density, wall_value=c.wall_value,
                full_resolution=c.full_resolution)
            geometry = self.cells.grid if c.full_resolution else self.cells.coarse
        stamp = rospy.Time.now()
        for publisher, grid in ((self.pub_now, now_grid), (self.pub_window, window_grid)):
            msg = grid_to_msg(geometry, c.frame_id, stamp)
            msg.data = grid.ravel().tolist()
            publisher.publish(msg)

    def publish_diagnostics(self) -> None:
        """What is served and why, on /diagnostics (WARN while the baselines are served)."""
        with self._lock:
            note, doing = self.learner.serving_note(), self.learner.describe()
            rows = self.model.n_rows_ if self.model is not None else 0
        level = DiagnosticStatus.WARN if note or self.model is None else DiagnosticStatus.OK
        item = DiagnosticStatus(name="traffic_gp: crowd model", hardware_id="traffic_gp",
                                level=level, message=note or doing,
                                values=[KeyValue("learner", doing), KeyValue("rows", str(rows))])
        self.pub_diagnostics.publish(DiagnosticArray(header=rospy.Header(stamp=rospy.Time.now()),
                                                     status=[item]))

    def _save_service(self, _req):
        try:
            path = self.save()
        except (TrafficError, OSError) as err:
            return TriggerResponse(success=False, message=str(err))
        return TriggerResponse(success=True, message=f"saved {path}")

    def save(self) -> str:
        if not self.config.model_path:
            raise TrafficError("~model_path is empty: nowhere to save")
        if self.model is None:
            raise TrafficError("no model to save yet")
        if isinstance(self.model, BaselineForecast):
            raise TrafficError(f"no GP to save yet ({self.learner.describe()}); save again once "
                               f"~status no longer says the baselines are served")
        with self._lock:
            if isinstance(self.model, PosteriorSnapshot):   # nothing learnt since it was loaded
                if os.path.abspath(self.model.path) != os.path.abspath(self.config.model_path):
                    shutil.copyfile(self.model.path, self.config.model_path)
            else:
                self.model.save(self.config.model_path, meta={"cell_size": self.config.cell_size})
            learned = {"source": self.config.source, "last_seq": self.feed_seq,
                       "central": (redact_url(self.config.central_url)
                                   if self.config.source == "central" else None),
                       "robots": {robot: list(tally) for robot, tally in self.learned.items()}}
        path = learned_path(self.config.model_path)
        with open(path + ".tmp", "w", encoding="utf-8") as stream:
            json.dump(learned, stream)
        os.replace(path + ".tmp", path)
        return self.config.model_path

    def shutdown(self) -> None:
        self._stop.set()
        if self.config.save_on_shutdown and self.model is not None and self.config.model_path:
            try:
                self.save()
            except TrafficError as err:
                rospy.logwarn(f"traffic_gp: not saved at shutdown: {err}")


def start() -> TrafficServer:
    """Read the node's parameters, build the server and wire it to ROS (after init_node)."""
    config = read_config(TrafficServerParams)
    warn_password_in_url(config.central_url)  # roslaunch prints parameters: say so at once
    server = TrafficServer(config)
    server.setup()
    return server
