"""Robot -> central push replication with CouchDB's own replicator (no ROS here).

A robot records into its local CouchDB-API store (pouchdb-server or Apache CouchDB); this module
asks that store to push the recorded database to a central CouchDB database, continuously and
checkpointed, with a `_replicator` document. It writes no replication protocol of its own: the
server's replicator reads the local `_changes` feed, asks the central database which revisions it
lacks (`_revs_diff`), copies them (`_bulk_docs`, attachments included) and records its checkpoint in
`_local/` documents on both sides, so after an outage or a restart it resumes where it stopped.

Why a `_replicator` document and not `POST /_replicate`: it is persistent (the replication comes
back when either server restarts) and, on pouchdb-server 4.2, the only form that retries while the
central server is unreachable (pouchdb-replicator starts it with `retry: true`; a continuous
`_replicate` there gives up at the first network error and cannot be cancelled or inspected).
Apache CouchDB 3 runs `_replicator` documents the same way (its scheduler; state under
`/_scheduler/docs/_replicator/<id>`).

What goes up (`ReplicationSpec`): a Mango `selector` on the replication, evaluated by the robot's
store, never by the central one: documents of kind "message" and "topic" of the chosen topics
(all topics by default; `local_topics` stay on the robot, e.g. camera images). Measured here: a
selector-filtered `_replicator` replication works on pouchdb-server 4.2 with a local source (the
filter runs inside the server; the HTTP `_changes?filter=_selector` path that can crash
pouchdb-server is not used) and is documented for CouchDB >= 2. Design documents (Mango indexes,
which every robot creates with its own revision and a CouchDB member account may not write) and
deletions (tombstones carry no `kind`) never match, so the central database gets no conflicting
index documents, and a robot's retention (ros_mongo.fleet.retention) never deletes anything centrally.

How far behind (`PendingTracker`): follows the local `_changes` feed and asks the central database
with `_revs_diff` which of the selected documents it holds (same `_id` and `_rev`). Pending = the
selected documents whose revision is not central yet; lag = their number and the age of the oldest
(seconds since this tracker first saw it). It keeps its own checkpoint in the local `_local/`
document `ros_mongo_tracker-<replication id>` (written only up to the oldest pending document).

Requests go through the one CouchDB client (ros_mongo.storage.couch_client: credentials, TLS,
one error mapping), raising this module's errors: `ReplicationUnavailable` (retry later:
unreachable, timeout, 5xx, 429), `ReplicationRefused` (the operator must act: 401, 403, a TLS
failure, a database the account may not create), `ReplicationError` (anything else, and bad
arguments). Messages never contain credentials: URLs are redacted and server answers scrubbed.
The central password is kept in the `_replicator` document of the robot's store (as CouchDB
itself does): protect that store.
"""
import base64
import json
import logging
import re
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple
from urllib.parse import quote

from ros_mongo.errors import StoreError, StoreRefused, StoreUnavailable
from ros_mongo.storage.couch_client import CouchClient, ErrorFamily
from ros_mongo.urls import scrub

__all__ = ["ReplicationError", "ReplicationUnavailable", "ReplicationRefused", "CouchDatabase",
           "ReplicationSpec", "ReplicationStatus", "PushReplication", "PendingTracker",
           "TrackerCounts", "replication_doc_id"]

logger = logging.getLogger(__name__)

REPLICATED_KINDS = ("message", "chunk", "topic")
# Documents per replication batch on a pouchdb-server store (its default is 100; Apache CouchDB's
# worker_batch_size defaults to 500). Each batch costs a _revs_diff, a _bulk_docs and two
# checkpoint writes, so at 100 Hz a backlog drains in larger steps.
POUCHDB_BATCH_SIZE = 500


class ReplicationError(StoreError):
    """A replication request failed or was malformed (the message quotes the redacted URL)."""


class ReplicationUnavailable(ReplicationError, StoreUnavailable):
    """Retry later: a server is unreachable, timed out or overloaded."""


class ReplicationRefused(ReplicationError, StoreRefused):
    """The operator must act: credentials, permissions or a database the account may not create."""


REPLICATION_ERRORS = ErrorFamily(ReplicationError, ReplicationUnavailable, ReplicationRefused)


class CouchDatabase(CouchClient):
    """One database on a CouchDB-API server (ros_mongo.storage.couch_client), raising the replication's
    errors; `url` is the server root (with any proxy prefix). TLS options as CouchClient's."""

    def __init__(self, url: str, *, timeout: float = 10.0, **tls):
        super().__init__(url, timeout=timeout, errors=REPLICATION_ERRORS, **tls)

    @property
    def url(self) -> str:
        return self.server_url

    def ensure_exists(self) -> bool:
        """Create the database if it is missing (True if created); ReplicationRefused when the
        account may not (CouchDB 3: only a server admin creates databases)."""
        if self.request("GET", "", ok=(200, 404)).status_code == 200:
            return False
        self.request("PUT", "", ok=(201, 202, 412))
        return True

    def revs_missing(self, revs: Dict[str, str]) -> Dict[str, List[str]]:
        """{id: missing revs} for the ids whose given revision this database lacks."""
        if not revs:
            return {}
        answer = self.json("POST", "/_revs_diff", json={i: [r] for i, r in revs.items()})
        return {i: entry.get("missing", []) for i, entry in answer.items() if entry.get("missing")}


@dataclass(frozen=True)
class ReplicationSpec:
    """Which documents go up: kinds "message" and "topic"; of `topics` only (all if empty); never
    of `local_topics`."""

    topics: Tuple[str, ...] = ()
    local_topics: Tuple[str, ...] = ()

    def __post_init__(self):
        for name in tuple(self.topics) + tuple(self.local_topics):
            if not isinstance(name, str) or not name.startswith("/"):
                raise ReplicationError(f"topic names start with '/': got {name!r}")
        overlap = sorted(set(self.topics) & set(self.local_topics))
        if overlap:
            raise ReplicationError(f"topics both replicated and local-only: {overlap}")

    def selector(self) -> Dict[str, Any]:
        """The Mango selector of the replication (also excludes design documents and deletions)."""
        selector: Dict[str, Any] = {"kind": {"$in": list(REPLICATED_KINDS)}}
        topic: Dict[str, Any] = {}
        if self.topics:
            topic["$in"] = sorted(self.topics)
        if self.local_topics:
            topic["$nin"] = sorted(self.local_topics)
        if topic:
            selector["topic"] = topic
        return selector

    def selects(self, doc: dict) -> bool:
        """The selector, evaluated here (the tracker and retention use the same rule)."""
        if doc.get("_deleted") or doc.get("kind") not in REPLICATED_KINDS:
            return False
        topic = doc.get("topic")
        if self.topics and topic not in self.topics:
            return False
        return topic not in self.local_topics


@dataclass
class ReplicationStatus:
    """The replication as the robot's store reports it."""

    state: str  # "stopped", "starting", "running", "error", "completed" (or CouchDB's scheduler word)
    reason: str = ""
    server_kind: str = ""


def _basic(auth: Tuple[str, str]) -> str:
    return "Basic " + base64.b64encode(f"{auth[0]}:{auth[1]}".encode()).decode("ascii")


class PushReplication:
    """The continuous, checkpointed push of a robot's database to a central database.

    `local` and `central` are CouchDatabase objects; `doc_id` names the `_replicator` documents on
    the robot's store (`<doc_id>.<run token>`; one robot and database per `doc_id`)."""

    def __init__(self, local: CouchDatabase, central: CouchDatabase, spec: ReplicationSpec, *,
                 doc_id: str):
        if not re.match(r"^[A-Za-z0-9][\w.\-]*$", doc_id):
            raise ReplicationError(f"replication document id must be letters, digits, '.', '-', "
                                   f"'_': got {doc_id!r}")
        self.local = local
        self.central = central
        self.spec = spec
        self.doc_id = doc_id
        self.replicator = local.sibling("_replicator")
        self._apache: Optional[bool] = None

    @classmethod
    def for_robot(cls, local: CouchDatabase, central: CouchDatabase, robot_id: str,
                  spec: Optional[ReplicationSpec] = None) -> "PushReplication":
        """The push of `robot_id`'s database `local` to `central` (all documents unless `spec`
        says otherwise), under that robot's `_replicator` document id."""
        return cls(local, central, spec or ReplicationSpec(),
                   doc_id=replication_doc_id(robot_id, local.name))

    def _is_apache(self) -> bool:
        if self._apache is None:
            self._apache = self.local.is_apache_couchdb()
        return self._apache

    def _endpoint(self, database: CouchDatabase, local_name_ok: bool) -> Any:
        if local_name_ok:
            return database.name  # pouchdb-server: the source is its own database (no HTTP hop)
        if not database.auth:
            return database.db_url
        if self._is_apache():
            return {"url": database.db_url, "headers": {"Authorization": _basic(database.auth)}}
        # pouchdb-server 4.2 turns an Authorization header back into a URL without escaping it:
        # a password holding '@', '/' and ':' then names another host, and nothing is replicated
        # (silently). Percent-encoded in the URL, which PouchDB decodes, every password works.
        user, password = (quote(part, safe="") for part in database.auth)
        scheme, rest = database.db_url.split("://", 1)
        return f"{scheme}://{user}:{password}@{rest}"

    def document(self, run: str = "") -> dict:
        """A new `_replicator` document (holds the central credentials: never log it). `run`
        makes each run's fields unique: pouchdb-replicator 4.2 takes a document whose fields equal
        those of a job it stopped for a duplicate of that job and never starts it."""
        doc = {"source": self._endpoint(self.local, not self._is_apache()),
               "target": self._endpoint(self.central, False),
               "continuous": True, "selector": self.spec.selector(), "ros_mongo_run": run}
        if not self._is_apache():
            doc["batch_size"] = POUCHDB_BATCH_SIZE
        return doc

    def _documents(self) -> List[dict]:
        """This replication's documents, `<doc_id>.<run token>` (normally one)."""
        params = {"include_docs": "true", "startkey": json.dumps(self.doc_id + "."),
                  "endkey": json.dumps(self.doc_id + ".\ufff0")}
        rows = self.replicator.json("GET", "/_all_docs", params=params).get("rows", [])
        return [row["doc"] for row in rows if row.get("doc")]

    def _same_job(self, doc: dict, wanted: dict) -> bool:
        return all(doc.get(k) == wanted[k] for k in ("source", "target", "continuous", "selector"))

    def start(self) -> bool:
        """Create (or correct) the replication; False if it was already running as wanted."""
        current = self._documents()
        if len(current) == 1 and self._same_job(current[0], self.document()) and \
                current[0].get("_replication_state") not in ("error", "completed"):
            return False
        self.trigger()
        return True

    def trigger(self) -> None:
        """Restart the replication now (it resumes from its checkpoint); starts it if stopped.

        Every run gets a document of its own (`<doc_id>.<run token>`, the token also in its
        fields): the old one is deleted, a new one created. pouchdb-server 4.2 refuses edits of a
        running replication's document, mistakes a re-created document for a duplicate of the job
        it replaced (and never starts it), and marks whatever document has the old id
        "completed" when the old job ends. The checkpoint (the replication id: source, target,
        selector) depends on neither the document id nor the token."""
        self.stop()
        run = uuid.uuid4().hex[:12]
        self.replicator.request("PUT", "/" + quote(f"{self.doc_id}.{run}", safe=""),
                                json=self.document(run), ok=(201, 202))

    def stop(self) -> bool:
        """Delete the replication's documents (it stops; its checkpoints stay)."""
        current = self._documents()
        for doc in current:
            self.replicator.request("DELETE", "/" + quote(doc["_id"], safe=""),
                                    params={"rev": doc["_rev"]}, ok=(200, 202, 404, 409))
        return bool(current)

    def status(self) -> ReplicationStatus:
        """Stopped, running, error ... as the robot's store reports it (reasons scrubbed)."""
        kind = "couchdb" if self._is_apache() else "pouchdb-server"
        current = self._documents()
        if not current:
            return ReplicationStatus("stopped", "no replication document", kind)
        doc = current[-1]
        if self._is_apache():
            response = self.local.request("GET", "/_scheduler/docs/_replicator/"
                                          + quote(doc["_id"], safe=""), server=True, ok=(200, 404))
            if response.status_code == 404:
                return ReplicationStatus("starting", "", kind)
            job = response.json()
            info = job.get("info") or {}
            reason = info.get("error", "") if isinstance(info, dict) else str(info)
            return ReplicationStatus(str(job.get("state")), self._scrub(str(reason or "")), kind)
        state = doc.get("_replication_state")
        if state == "triggered":
            return ReplicationStatus("running", "", kind)
        if state is None:
            return ReplicationStatus("starting", "", kind)
        return ReplicationStatus(str(state), self._scrub(str(doc.get("_replication_state_reason", ""))),
                                 kind)

    def _scrub(self, text: str) -> str:
        return scrub(scrub(text, self.central.full_url), self.local.full_url)

    def central_problem(self) -> Optional[ReplicationError]:
        """None when the central database answers this account (404: up, database not created
        yet); else why not: ReplicationRefused (credentials, permissions, TLS verification),
        ReplicationUnavailable (unreachable), ReplicationError (anything else)."""
        try:
            self.central.request("GET", "", ok=(200, 404))
            return None
        except ReplicationError as err:
            return err


@dataclass
class TrackerCounts:
    """What the tracker knows after a poll."""

    pending: int = 0            # selected documents not central yet (tracked + untracked estimate)
    tracked: int = 0            # of them, followed one by one
    untracked: int = 0          # changes not read yet because `max_tracked` was reached
    confirmed: int = 0          # documents confirmed central since the tracker started
    lag_seconds: float = 0.0    # age of the oldest pending document (since first seen)
    last_check: float = 0.0     # wall time of the last complete check
    error: str = ""             # the last poll's error ("" when it succeeded)
    extra: Dict[str, Any] = field(default_factory=dict)


class PendingTracker:
    """Pending documents and lag of a push replication (see the module docstring)."""

    def __init__(self, local: CouchDatabase, central: CouchDatabase, spec: ReplicationSpec, *,
                 checkpoint_id: str, max_tracked: int = 100000, page: int = 500,
                 clock=time.time):
        if max_tracked < 1 or page < 1:
            raise ReplicationError(f"max_tracked and page must be >= 1: got {max_tracked}, {page}")
        self.local = local
        self.central = central
        self.spec = spec
        self.checkpoint_path = "/_local/" + quote(f"ros_mongo_tracker-{checkpoint_id}", safe="")
        self.max_tracked = max_tracked
        self.page = page
        self.clock = clock
        self.since: Any = None  # None: not loaded yet
        # id -> (rev, first seen, seq before its change), in feed order
        self.pending: Dict[str, Tuple[str, float, Any]] = {}  # insertion order = feed order
        self.counts = TrackerCounts()
        self._saved_at = 0.0

    def _load_checkpoint(self) -> None:
        response = self.local.request("GET", self.checkpoint_path, ok=(200, 404))
        self.since = response.json().get("since", 0) if response.status_code == 200 else 0

    def _read_changes(self) -> bool:
        """Reads one page of changes; True if there may be more."""
        params = {"since": str(self.since), "include_docs": "true", "limit": str(self.page)}
        answer = self.local.json("GET", "/_changes", params=params)
        previous = self.since
        now = self.clock()
        for change in answer.get("results", []):
            doc = change.get("doc") or {}
            if not change.get("deleted") and self.spec.selects(doc):
                old = self.pending.pop(change["id"], None)
                first_seen = old[1] if old else now
                self.pending[change["id"]] = (doc.get("_rev") or change["changes"][0]["rev"],
                                              first_seen, previous)
            previous = change.get("seq", previous)
        self.since = answer.get("last_seq", previous)
        return len(answer.get("results", [])) >= self.page

    def _confirm(self) -> int:
        confirmed = 0
        ids = list(self.pending)
        for start in range(0, len(ids), 1000):
            chunk = {i: self.pending[i][0] for i in ids[start:start + 1000]}
            missing = self.central.revs_missing(chunk)
            for doc_id in chunk:
                if doc_id not in missing:
                    del self.pending[doc_id]
                    confirmed += 1
        return confirmed

    def _untracked(self) -> int:
        answer = self.local.json("GET", "/_changes", params={
            "since": str(self.since), "limit": "1"})
        if "pending" in answer:  # CouchDB >= 2
            return int(answer["pending"]) + len(answer.get("results", []))
        info = self.local.json("GET", "")
        if isinstance(info.get("update_seq"), int) and isinstance(self.since, int):
            return max(0, info["update_seq"] - self.since)
        return len(answer.get("results", []))

    def checkpoint(self) -> Any:
        """The feed position before the oldest pending document (all earlier ones are central)."""
        if self.pending:
            return next(iter(self.pending.values()))[2]
        return self.since

    def _save_checkpoint(self) -> None:
        current = self.local.request("GET", self.checkpoint_path, ok=(200, 404))
        doc = {"since": self.checkpoint()}
        if current.status_code == 200:
            doc["_rev"] = current.json()["_rev"]
        self.local.request("PUT", self.checkpoint_path, json=doc, ok=(200, 201, 202, 409))

    def poll(self, *, save_every: float = 10.0) -> TrackerCounts:
        """Read new local changes, confirm against central; never raises ReplicationError (the
        error is in the counts, with the last known numbers)."""
        try:
            if self.since is None:
                self._load_checkpoint()
            while len(self.pending) < self.max_tracked and self._read_changes():
                pass
            untracked = self._untracked() if len(self.pending) >= self.max_tracked else 0
            self.counts.confirmed += self._confirm()
            now = self.clock()
            self.counts.tracked = len(self.pending)
            self.counts.untracked = untracked
            self.counts.pending = len(self.pending) + untracked
            self.counts.lag_seconds = (now - min(v[1] for v in self.pending.values())
                                       if self.pending else 0.0)
            self.counts.last_check = now
            self.counts.error = ""
            if now - self._saved_at >= save_every:
                self._save_checkpoint()
                self._saved_at = now
        except ReplicationError as err:
            self.counts.error = str(err)
            if self.pending:
                self.counts.lag_seconds = self.clock() - min(v[1] for v in self.pending.values())
        return self.counts


def replication_doc_id(robot_id: str, database: str) -> str:
    """`ros_mongo-<robot>-<database>` with anything but letters, digits, '.', '-' made '_'."""
    return re.sub(r"[^\w.\-]", "_", f"ros_mongo-{robot_id}-{database}")
