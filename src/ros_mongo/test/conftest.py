"""ros_mongo test set-up: the shared test modules (ros_mongo_samples, recorder_harness) are
importable, the recorder's /diagnostics watcher is a fixture, and the CouchDB tests run against
both CouchDB-API servers.

`couchdb_url` and `db_url` (ros_harness's fixtures, overridden here) give a fresh database on
pouchdb-server AND on a real Apache CouchDB 3 node (ros_harness `apache_couchdb`: one node for the
whole run, one database per test, created by the admin; the URL is that of a database *member*,
as a robot gets; skipped where ../shared/couchdb is absent). A test whose behaviour cannot differ
between the two and that costs many seconds pins one server:
`@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)`, or for `db_url`
`@pytest.mark.parametrize("db_server", ["pouchdb", "mongodb"], indirect=True)`.
"""
import sys
import uuid
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

DB_KINDS = ["pouchdb", "apache", "mongodb"]


def fresh_name(prefix: str = "test_") -> str:
    return prefix + uuid.uuid4().hex[:12]


@pytest.fixture
def couchdb_url(couch_server) -> str:
    """A fresh database on each CouchDB-API server (the member's URL on Apache CouchDB)."""
    return couch_server.database_url(fresh_name())


@pytest.fixture(params=DB_KINDS)
def db_server(request):
    """The shared pouchdb-server, Apache CouchDB node and nx-27017 server, one after the other
    (`.database_url(name)`: a database the product may use; on Apache CouchDB created by the
    admin, as its member)."""
    server = {"pouchdb": "couchdb_server", "apache": "apache_couchdb", "mongodb": "mongodb_server"}
    return request.getfixturevalue(server[request.param])


@pytest.fixture
def db_url(db_server) -> str:
    """A fresh database on each server of `db_server`."""
    return db_server.database_url(fresh_name())


@pytest.fixture
def diagnostics(rospy_node):
    """The recorder's latest /diagnostics status (recorder_harness.Diagnostics)."""
    from recorder_harness import Diagnostics

    watcher = Diagnostics()
    yield watcher
    watcher.close()
