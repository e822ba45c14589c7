"""Follow a CouchDB database's `_changes` feed: stored messages as they arrive, resumable (no ROS).

A learner that trains from the central fleet database (every robot's replicated messages) follows
its `_changes` feed from a sequence it saved: `ChangesFollower(url, selector=..., since=saved)`,
then `poll()` (one request: the next page of changes) or `follow(stop_event)` (forever: polls
every `poll_interval` seconds once caught up, reconnecting with back-off while the server is
down). No long-poll: pouchdb-server ignores the long-poll `timeout` and holds the request until a
change comes, which would also keep a follower from stopping. Each selected change comes as a
`FeedItem`: the decoded `StoredMessage` (through ros_mongo.storage.documents, as the CouchDB backend
reads it) and `seq`, the feed position just after it; save the `seq` of the last item the
learner has folded in, and a new follower started `since` it yields only later changes.
Order: the server's feed order, kept as it is (so that every `seq` resumes exactly): write order
on pouchdb-server; Apache CouchDB interleaves the feeds of a database's shards (q = 2 by default,
also on one node) in the order their rows reach it, anew on each request, so there two messages
may come in another order than they were written, and after a resume the changes of one shard may
fill a page before the next change of the other comes. A learner that needs time order sorts by
`receive_time`, or the admin creates the database with one shard (`PUT /db?q=1`).
A chunk (ros_mongo.storage.chunks: many messages of a topic in one document) yields its messages one by
one, with their own ids; the position after a message inside a chunk is
`{"since": <the chunk's own feed position>, "chunk": <its id>, "done": <messages yielded>}`
(JSON-able like a sequence). A follower started from it reads the rest of that chunk from the
chunk document itself (`GET /db/<id>`: a chunk is written once and never changes), then the feed
after the chunk, and drops the chunk if the feed sends it again (CouchDB's feed promises each
change at least once). A position saved by an earlier release held the feed position before the
chunk: it resumes the same way (the chunk, coming again in the feed, is dropped).

The selector is a Mango selector evaluated here on each document (`selects`, ros_mongo.storage.mango:
the answer Apache CouchDB gives for it; e.g. `$eq null` matches a present null only). It is not
sent to the server: `_changes?filter=_selector` is documented for CouchDB >= 2 but kills
pouchdb-server, so both servers get the plain feed and the follower drops the documents it does
not want. Deletions (a robot's retention deletes only locally, but an operator may purge
centrally) and design documents are never selected.

Errors: `poll` raises ReplicationUnavailable (retry later) / ReplicationRefused /
ReplicationError (ros_mongo.fleet.replication); `follow` retries all of them, with back-off, and keeps
the last one in `last_error`. Messages never contain credentials (URLs redacted).
"""
import logging
import threading
from typing import Any, Dict, Iterator, List, NamedTuple, Optional
from urllib.parse import quote

import pybase64

from ros_mongo.errors import StoreError
from ros_mongo.fleet.replication import CouchDatabase, ReplicationError
from ros_mongo.records import StoredMessage
from ros_mongo.storage.chunks import expand
from ros_mongo.storage.couch import CouchStore
from ros_mongo.storage.documents import stored_message
from ros_mongo.storage.mango import SelectorError, compile_selector

__all__ = ["FeedItem", "ChangesFollower"]

logger = logging.getLogger(__name__)


class FeedItem(NamedTuple):
    """One selected change: the stored message and the feed position just after it."""

    seq: Any
    message: StoredMessage


class ChangesFollower:
    """Follows the `_changes` feed of the CouchDB database at `url` (credentials allowed in `url`;
    never shown) from `since`, yielding the message documents that match `selector`. `tls`:
    tls_ca_file, tls_cert_file, tls_key_file, tls_verify (ros_mongo.storage.couch_client)."""

    def __init__(self, url: str, *, selector: Optional[Dict[str, Any]] = None, since: Any = 0,
                 poll_interval: float = 1.0, page: int = 200, timeout: float = 10.0,
                 backoff_min: float = 0.5, backoff_max: float = 30.0, **tls):
        if page < 1 or poll_interval <= 0 or not 0 < backoff_min <= backoff_max:
            raise ReplicationError(f"bad follower settings: page {page}, poll interval "
                                   f"{poll_interval} s, back-off {backoff_min}..{backoff_max} s")
        self.selector = dict({"kind": "message"}, **(selector or {}))
        try:
            self._matches = compile_selector(self.selector)
        except SelectorError as err:
            raise ReplicationError(f"bad follower selector: {err}") from None
        self.database = CouchDatabase(url, timeout=timeout, **tls)
        # decoding (types, attachments) through the same client; the store never connects itself
        self.store = CouchStore(url, client=self.database)
        self.since: Any = since if since is not None else 0
        self.poll_interval = poll_interval
        self.page = page
        self.backoff_min = backoff_min
        self.backoff_max = backoff_max
        self.last_error = ""
        self.caught_up = False  # the last poll reached the end of the feed
        self.skipped = 0  # selected documents that could not be decoded
        self.resumed_chunk: Optional[str] = None  # the chunk resumed inside: dropped from the feed

    @property
    def shown(self) -> str:
        """The database URL without its password."""
        return self.database.shown

    def selects(self, doc: Dict[str, Any]) -> bool:
        """Whether a changed document is wanted (never a deletion or a design document)."""
        if not doc or doc.get("_deleted") or str(doc.get("_id", "")).startswith("_design/"):
            return False
        return self._matches(doc)

    def _decode(self, doc: Dict[str, Any], raw: Optional[bytes] = None) -> Optional[StoredMessage]:
        try:
            if raw is None and doc.get("raw") is not None:
                raw = pybase64.b64decode(doc["raw"])
            return stored_message(doc, raw, self.store._load_blob, self.store.message_class)
        except (StoreError, ValueError, TypeError) as err:
            self.skipped += 1
            logger.warning("changes of %s: skipped document %r: %s", self.shown, doc.get("_id"), err)
            return None

    def poll(self) -> List[FeedItem]:
        """One request: the selected changes among the next `page` changes after `since` (from a
        position inside a chunk: the rest of that chunk, read from its document). Advances
        `since`; `caught_up` tells whether the feed's end was reached."""
        if isinstance(self.since, dict) and "chunk" in self.since:
            return self._rest_of_chunk(self.since)
        params = {"since": str(self.since), "include_docs": "true", "limit": str(self.page)}
        answer = self.database.json("GET", "/_changes", params=params)
        self.caught_up = len(answer.get("results", [])) < self.page
        items: List[FeedItem] = []
        for change in answer.get("results", []):
            seq = change.get("seq", self.since)
            doc = change.get("doc") or {}
            if change.get("deleted") or doc.get("_id") == self.resumed_chunk:
                pass  # a deletion, or the chunk resumed inside (read from its document)
            elif doc.get("kind") == "chunk":
                items += self._chunk_items(doc, seq, 0)
            elif self.selects(doc):
                message = self._decode(doc)
                if message is not None:
                    items.append(FeedItem(seq, message))
            self.since = seq
        self.since = answer.get("last_seq", self.since)
        return items

    def _rest_of_chunk(self, position: Dict[str, Any]) -> List[FeedItem]:
        """The selected messages of the chunk `position` points into, after its first `done`,
        from the chunk document (gone: none); then `since` is the feed position in `position`."""
        chunk_id = str(position["chunk"])
        doc = self.database.json("GET", "/" + quote(chunk_id, safe=""), ok=(200, 404))
        items: List[FeedItem] = []
        if doc.get("_id") == chunk_id and doc.get("kind") == "chunk" and not doc.get("_deleted"):
            items = self._chunk_items(doc, position["since"], int(position.get("done", 0)),
                                      plain_last=False)
        self.resumed_chunk = chunk_id
        self.since = position["since"]
        self.caught_up = False
        return items

    def _chunk_items(self, doc: Dict[str, Any], seq: Any, done: int, *,
                     plain_last: bool = True) -> List[FeedItem]:
        """The selected messages of a chunk (after the first `done`), each with its position:
        the chunk's feed position `seq` (after its last message, when `plain_last`) or inside it."""
        try:
            messages = [m for m, _ in expand(doc, None)]
            count = len(messages)
            wanted = [i for i in range(done, count) if self.selects(messages[i])]
            raw = self.store._load_blob(doc["_id"]) if wanted else b""
            parts = expand(doc, raw, self.store.chunk_fields(doc)) if wanted else []
        except (StoreError, ValueError, TypeError, KeyError) as err:
            self.skipped += 1
            logger.warning("changes of %s: skipped chunk %r: %s", self.shown, doc.get("_id"), err)
            return []
        items = []
        for index in wanted:
            message, data = parts[index]
            stored = self._decode(message, data)
            if stored is not None:
                inside = index < count - 1 or not plain_last
                position = {"since": seq, "chunk": doc["_id"], "done": index + 1} if inside else seq
                items.append(FeedItem(position, stored))
        return items

    def follow(self, stop: threading.Event) -> Iterator[FeedItem]:
        """Selected changes, forever (until `stop` is set): polls every `poll_interval` seconds
        once caught up; reconnects with exponential back-off while the server is unreachable or
        answers errors."""
        delay = self.backoff_min
        while not stop.is_set():
            try:
                items = self.poll()
            except ReplicationError as err:
                if str(err) != self.last_error:
                    logger.warning("changes of %s: %s (retrying)", self.shown, err)
                self.last_error = str(err)
                stop.wait(delay)
                delay = min(self.backoff_max, delay * 2)
                continue
            self.last_error = ""
            delay = self.backoff_min
            yield from items
            if self.caught_up:
                stop.wait(self.poll_interval)

    def close(self) -> None:
        """Close the HTTP sessions."""
        self.database.close()
