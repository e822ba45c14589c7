"""ROS layer of robot -> central replication: the ros_mongo_replicator node (see ros_mongo.replication)."""
import os
import socket
import threading
import time
from dataclasses import dataclass
from typing import List, Optional

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_srvs.srv import Trigger, TriggerResponse

from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from robot_common.ros_node import read_config, run_node
from ros_mongo.replication import (
    CouchDatabase,
    PendingTracker,
    PushReplication,
    ReplicationError,
    ReplicationSpec,
    ReplicationStatus,
)
from ros_mongo.retention import Retention
from ros_mongo.urls import CredentialsError, redact_url, with_credentials

__all__ = ["ReplicatorConfig", "ReplicatorNode", "main"]

CENTRAL_PASSWORD_ENV = "ROS_MONGO_CENTRAL_PASSWORD"
CENTRAL_USER_ENV = "ROS_MONGO_CENTRAL_USER"
RESTART_AFTER = 10.0  # seconds between restarts of a replication the store reports ended or failed


@dataclass
class ReplicatorConfig(NodeConfig):
    local_url: str = param("http://127.0.0.1:5984/robot_data",
                           "the robot's CouchDB-API database that the recorder writes (password-free)")
    central_url: str = param("", "the central CouchDB database URL, e.g. http://central:5984/fleet "
                                 "(password-free; required)")
    central_credentials_file: str = param("", "file with user:password for central_url (or set "
                                              "ROS_MONGO_CENTRAL_USER / ROS_MONGO_CENTRAL_PASSWORD)")
    robot_id: str = param("", "this robot's id (names the replication); empty: the host name")
    topics: List[str] = param([], "topics whose documents go up; empty: every recorded topic")
    local_topics: List[str] = param([], "topics that stay on the robot (e.g. camera images)")
    create_central_db: bool = param(True, "create the central database if missing (needs an admin "
                                          "account on CouchDB 3; otherwise an admin creates it)")
    autostart: bool = param(True, "start the replication when the node starts")
    status_period: float = param(1.0, "seconds between checks and /diagnostics messages", minimum=0.1)
    lag_warn: float = param(30.0, "seconds of lag above which the status is WARN", minimum=0.0)
    max_tracked: int = param(100000, "pending documents followed one by one (beyond: estimated)",
                             minimum=1)
    retention_age: float = param(0.0, "delete local messages held centrally and older than this "
                                      "(seconds); 0: keep everything", minimum=0.0)
    retention_period: float = param(60.0, "seconds between retention passes", minimum=1.0)
    retention_batch: int = param(5000, "documents read per retention pass, at most", minimum=1)
    timeout: float = param(10.0, "seconds a database request may take", minimum=0.1)

    def check(self) -> None:
        if not self.central_url:
            raise ConfigError("~central_url is required (the central CouchDB database URL)")
        for name, value in (("local_url", self.local_url), ("central_url", self.central_url)):
            if not value.startswith(("http://", "https://")):
                raise ConfigError(f"~{name} must be an http(s):// CouchDB database URL, got "
                                  f"{redact_url(value)!r}")


class ReplicatorNode:
    """ros_mongo_replicator: keeps a continuous push replication from the robot's store to central.

    Parameters: `ReplicatorConfig` (config/ros_mongo_replicator.yaml).
    Publishes: /diagnostics (diagnostic_msgs/DiagnosticArray), status "ros_mongo_replicator:
        <robot>": state, central_reachable, pending_docs, lag_docs, lag_seconds, confirmed,
        retention_deleted, last_error (redacted), local, central (redacted URLs).
    Services (std_srvs/Trigger): ~start (create the replication), ~stop (delete it; checkpoints
        stay), ~trigger (restart it now: it resumes from its checkpoint).
    The replication runs inside the robot's store: it goes on when this node stops.
    """

    def __init__(self, config: ReplicatorConfig):
        self.config = config
        self.robot_id = config.robot_id or socket.gethostname()
        environ = {"ROS_MONGO_DB_PASSWORD": os.environ.get(CENTRAL_PASSWORD_ENV, ""),
                   "ROS_MONGO_DB_USER": os.environ.get(CENTRAL_USER_ENV, "")}
        environ = {k: v for k, v in environ.items() if v}
        central_url = with_credentials(config.central_url,
                                       credentials_file=config.central_credentials_file or None,
                                       environ=environ)
        self.local = CouchDatabase(config.local_url, timeout=config.timeout)
        self.central = CouchDatabase(central_url, timeout=config.timeout)
        self.spec = ReplicationSpec(tuple(config.topics), tuple(config.local_topics))
        self.replication = PushReplication.for_robot(self.local, self.central, self.robot_id, self.spec)
        self.tracker = PendingTracker(self.local, self.central, self.spec,
                                      checkpoint_id=self.replication.doc_id,
                                      max_tracked=config.max_tracked)
        self.retention: Optional[Retention] = None
        if config.retention_age > 0:
            self.retention = Retention(self.local, self.central, self.spec,
                                       older_than=config.retention_age,
                                       max_docs=config.retention_batch, clock=rospy.get_time)
        self.lock = threading.Lock()
        self.wanted = config.autostart
        self.started = False
        self.reachable: Optional[bool] = None
        self.status = ReplicationStatus("stopped")
        self.last_error = ""
        self._last_retention = 0.0
        self._restarted_at = 0.0

    def setup(self) -> "ReplicatorNode":
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=10)
        rospy.Service("~start", Trigger, self._on_start)
        rospy.Service("~stop", Trigger, self._on_stop)
        rospy.Service("~trigger", Trigger, self._on_trigger)
        self._thread = threading.Thread(target=self._loop, name="replicator", daemon=True)
        self._thread.start()
        rospy.loginfo("replicating %s -> %s (robot %s, selector %s)", self.local.shown,
                      self.central.shown, self.robot_id, self.spec.selector())
        return self

    # -- services ----------------------------------------------------------------------------
    def _service(self, action, done: str) -> TriggerResponse:
        with self.lock:
            try:
                action()
            except ReplicationError as err:
                self.last_error = str(err)
                return TriggerResponse(success=False, message=str(err))
        return TriggerResponse(success=True, message=done)

    def _on_start(self, _req) -> TriggerResponse:
        def start():
            self.wanted = True
            self._ensure_started()
        return self._service(start, "replication started")

    def _on_stop(self, _req) -> TriggerResponse:
        def stop():
            self.wanted = False
            self.replication.stop()
            self.started = False
        return self._service(stop, "replication stopped (checkpoints kept)")

    def _on_trigger(self, _req) -> TriggerResponse:
        def trigger():
            self.wanted = True
            self.replication.trigger()
            self.started = True
        return self._service(trigger, "replication restarted from its checkpoint")

    # -- work --------------------------------------------------------------------------------
    def _ensure_started(self) -> None:
        # the store's replicator must find the database made by the store itself: a replication
        # of a missing database (pouchdb-server) follows a database of its own, never written
        self.local.ensure_exists()
        if self.config.create_central_db:
            self.central.ensure_exists()
        self.replication.start()
        self.started = True

    def _loop(self) -> None:
        rate = rospy.Rate(1.0 / self.config.status_period)
        while not rospy.is_shutdown():
            with self.lock:
                self._step()
            self._publish()
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break

    def _step(self) -> None:
        reachable = self.replication.central_reachable()
        came_back = reachable and self.reachable is False
        self.reachable = reachable
        try:
            if self.wanted and not self.started:
                self._ensure_started()
            elif self.wanted and came_back:
                self._restart("central database reachable again")  # skips the retry back-off
            self.status = self.replication.status()
            if self.status.state in ("error", "failed", "crashing", "completed"):
                if self.status.reason:
                    self.last_error = self.status.reason
                if self.wanted and reachable and time.monotonic() - self._restarted_at > RESTART_AFTER:
                    self._restart(f"replication {self.status.state}")
        except ReplicationError as err:
            self.last_error = str(err)
        counts = self.tracker.poll()
        if counts.error:
            self.last_error = counts.error
        if self.retention and reachable and rospy.get_time() - self._last_retention >= \
                self.config.retention_period:
            self._last_retention = rospy.get_time()
            try:
                self.retention.run_once()
            except ReplicationError as err:
                self.last_error = str(err)

    def _restart(self, why: str) -> None:
        self._restarted_at = time.monotonic()
        self.replication.trigger()
        rospy.loginfo("%s: replication restarted (it resumes from its checkpoint)", why)

    def _publish(self) -> None:
        counts = self.tracker.counts
        status = DiagnosticStatus(name=f"ros_mongo_replicator: {self.robot_id}",
                                  hardware_id=self.central.shown)
        if self.status.state in ("error", "failed", "crashing"):
            status.level, status.message = DiagnosticStatus.ERROR, f"replication {self.status.state}"
        elif not self.wanted:
            status.level, status.message = DiagnosticStatus.WARN, "replication stopped by request"
        elif self.reachable is False:
            status.level, status.message = DiagnosticStatus.WARN, "central unreachable: keeping data locally"
        elif counts.lag_seconds > self.config.lag_warn:
            status.level, status.message = DiagnosticStatus.WARN, f"lagging {counts.lag_seconds:.0f} s"
        else:
            status.level, status.message = DiagnosticStatus.OK, f"replication {self.status.state}"
        values = {"state": self.status.state, "central_reachable": str(self.reachable),
                  "pending_docs": counts.pending, "lag_docs": counts.pending,
                  "lag_seconds": f"{counts.lag_seconds:.3f}", "confirmed": counts.confirmed,
                  "retention_deleted": self.retention.total_deleted if self.retention else 0,
                  "last_error": self.last_error, "local": self.local.shown,
                  "central": self.central.shown, "server": self.status.server_kind}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = rospy.Time.now()
        self.diagnostics.publish(array)


def _start() -> ReplicatorNode:
    return ReplicatorNode(read_config(ReplicatorConfig)).setup()


def main() -> int:
    """The ros_mongo_replicator executable: exit status 1 with one line on a bad configuration."""
    return run_node("ros_mongo_replicator", _start, loggers=("ros_mongo",),
                    fatal=(ReplicationError, CredentialsError, ValueError))
