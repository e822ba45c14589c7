"""Real ROS and database processes for tests, demos and benchmarks (no mocks)."""
from ros_harness.apache_couchdb import ApacheCouchDB, CouchDBCluster
from ros_harness.errors import HarnessError, ProcessDied
from ros_harness.fault_proxy import FaultProxy
from ros_harness.launching import LaunchSet
from ros_harness.processes import (
    ManagedProcess,
    MongoWireServer,
    PouchDBServer,
    RosCore,
    RosLaunch,
    free_port,
    http_get_json,
    master_graph,
    wait_for_subscriber,
    wait_until,
)

__all__ = [
    "ApacheCouchDB",
    "CouchDBCluster",
    "FaultProxy",
    "HarnessError",
    "ProcessDied",
    "LaunchSet",
    "ManagedProcess",
    "MongoWireServer",
    "PouchDBServer",
    "RosCore",
    "RosLaunch",
    "free_port",
    "http_get_json",
    "master_graph",
    "wait_for_subscriber",
    "wait_until",
]
