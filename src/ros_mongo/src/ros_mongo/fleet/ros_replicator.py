"""ROS layer of robot -> central replication: the ros_mongo_replicator node (fleet.replication)."""
import os
import socket
import threading
import time
from typing import Optional

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_srvs.srv import Trigger, TriggerResponse

from robot_common.ros_node import read_config
from ros_mongo.fleet.replication import (
    CouchDatabase,
    PendingTracker,
    PushReplication,
    ReplicationError,
    ReplicationSpec,
    ReplicationStatus,
)
from ros_mongo.fleet.retention import Retention
from ros_mongo.params import ReplicatorParams
from ros_mongo.urls import warn_password_in_url, with_credentials

__all__ = ["ReplicatorNode", "start"]

CENTRAL_PASSWORD_ENV = "ROS_MONGO_CENTRAL_PASSWORD"
CENTRAL_USER_ENV = "ROS_MONGO_CENTRAL_USER"
RESTART_AFTER = 10.0  # seconds between restarts of a replication the store reports ended or failed


class ReplicatorNode:
    """ros_mongo_replicator: keeps a continuous push replication from the robot's store to central.

    Parameters: `ReplicatorParams` (config/ros_mongo_replicator.yaml).
    Publishes: /diagnostics (diagnostic_msgs/DiagnosticArray), status "ros_mongo_replicator:
        <robot>": state, central_reachable, pending_docs, lag_docs, lag_seconds, confirmed,
        retention_deleted, last_error (redacted), local, central (redacted URLs); ERROR with the
        reason while central refuses the account, fails TLS verification or cannot be reached.
    Services (std_srvs/Trigger): ~start (create the replication), ~stop (delete it; checkpoints
        stay), ~trigger (restart it now: it resumes from its checkpoint).
    The replication runs inside the robot's store: it goes on when this node stops.
    """

    def __init__(self, config: ReplicatorParams):
        self.config = config
        self.robot_id = config.robot_id or socket.gethostname()
        environ = {"ROS_MONGO_DB_PASSWORD": os.environ.get(CENTRAL_PASSWORD_ENV, ""),
                   "ROS_MONGO_DB_USER": os.environ.get(CENTRAL_USER_ENV, "")}
        environ = {k: v for k, v in environ.items() if v}
        central_url = with_credentials(config.central_url,
                                       credentials_file=config.central_credentials_file or None,
                                       environ=environ)
        warn_password_in_url(config.local_url)  # open_store would; CouchDatabase does not
        self.local = CouchDatabase(config.local_url, timeout=config.timeout)
        self.central = CouchDatabase(central_url, timeout=config.timeout, **config.central_tls())
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
        self.central_error = ""  # why central cannot be reached or refuses this account
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
        problem = self.replication.central_problem()
        reachable = problem is None
        came_back = reachable and self.reachable is False
        self.reachable = reachable
        self.central_error = "" if problem is None else str(problem)
        if problem is not None:
            self.last_error = str(problem)
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
        elif self.central_error:  # redacted: credentials, certificate or network; data kept locally
            status.level = DiagnosticStatus.ERROR
            status.message = f"central not replicating (data kept locally): {self.central_error}"
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


def start() -> ReplicatorNode:
    """Build the replicator node from its parameters and wire it to ROS (for run_node)."""
    return ReplicatorNode(read_config(ReplicatorParams)).setup()
