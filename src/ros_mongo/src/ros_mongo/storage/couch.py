"""CouchDB backend: a small layer over one requests.Session (see the README for why no client
library). Works with Apache CouchDB >= 2 and pouchdb-server.

Layout: one document per message (`kind: "message"`); serialized bytes up to the blob threshold
inline as base64 (`raw`), larger ones as the attachment `raw` (so the document body stays far below
CouchDB's 8,000,000-byte limit, which is also enforced here because pouchdb-server does not);
one document per topic and type (`kind: "topic"`, id `topic-<hash>`). Mango indexes on
(topic, receive_time) and (receive_time); reads page through `_find` sorted by receive time.

Writes: documents with inline bytes go in one `_bulk_docs` per batch (the server makes their
revision; a conflict means an earlier attempt stored it). A document with attachments (a large
message, a chunk) goes in one `multipart/related` `PUT /db/<id>?new_edits=false`: its JSON, then
its attachments as raw bytes (no base64: a quarter less on the link, no encoding on the robot),
with the revision `message_rev(id)` ("1-" + a hash of the id), as CouchDB's replicator writes
documents. The same id always comes with the same revision, so sending a message again (a retry of
a write that did land, a spool drained twice, a second writer) is a no-op on the server: no second
document, no conflict, no new change in the feed, and a document deleted since stays deleted. The
recorder writes them so, one request each (`insert_records(look_up=False)`); other writers look up
first which are stored (one `_all_docs` request per batch), for an exact count of those newly
stored and to leave alone a document an older release stored with a revision the server made (a
write with another revision would add a second, equal revision). A multipart write that gets no
answer in time (an Apache CouchDB 3.5 cluster with a node down never answers one, measured)
turns multipart off for `MULTIPART_PAUSE` (600 s): attachments then go base64 inside
`_bulk_docs` with `new_edits: false` and the same revision, as before 2026-11-29. Both kinds read
back alike, and as documents written before (base64 attachments in `_bulk_docs`: the same
document).

Least privilege: recording needs only a database *member* account (document writes). Creating the
database and the Mango indexes (design documents) is tried once, when the account may; otherwise
it is skipped with one warning, and reads go through `_all_docs` id ranges (ids sort by receive
time) with `_find` (no sort) doing the matching: the same answers, slower.

URLs, credentials, TLS options (`tls_ca_file`, `tls_cert_file`, `tls_key_file`, `tls_verify`)
and the mapping of answers to errors: ros_mongo.storage.couch_client, the one CouchDB client.

Answers (see ros_mongo.errors): connection errors, timeouts, a truncated or non-JSON body, 429,
5xx (500 `timeout` included) -> StoreUnavailable (a write's answer may take `timeout` plus
one second per 500 KB of its body); 401, 403, 500 `error_saving_ddoc` forbidden, a
missing database the account may not create -> StoreRefused; 413 (`document_too_large` names the
document) and 400 on `_bulk_docs` -> BatchTooLarge, on a document's own PUT -> that document
refused on its own merits; 202 (no write quorum) -> the documents are looked up, and
StoreUnavailable unless every one is there.
"""
import dataclasses
import hashlib
import heapq
import json
import logging
import time
from typing import Dict, Iterator, List, Optional, Tuple
from urllib.parse import quote

import orjson
import pybase64
import requests

from ros_mongo.errors import BatchTooLarge, QueryError, StoreError, StoreRefused, StoreUnavailable
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo
from ros_mongo.storage.base import MessageStore, register_backend
from ros_mongo.storage.chunks import (
    CHUNK_KEYS,
    CHUNK_SPAN,
    ChunkRecord,
    chunk_doc,
    expand,
    sorted_messages,
)
from ros_mongo.storage.couch_client import CouchClient
from ros_mongo.storage.couch_multipart import inline_document, multipart_document
from ros_mongo.storage.couch_pages import Pager, id_bound, take
from ros_mongo.storage.documents import META_KEYS, message_doc, query_conditions, to_selector, topic_doc
from ros_mongo.storage.mango import compile_selector

__all__ = ["CouchStore", "MAX_DOC_BYTES", "message_rev"]

log = logging.getLogger(__name__)

MAX_DOC_BYTES = 8_000_000
_INDEXES = {"ros_mongo_topic_time": ["topic", "receive_time"], "ros_mongo_time": ["receive_time"]}
_DB_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_$()+-/")
_READ_RETRIES = 4    # a read answered "retry later" is tried this many times (backoff 0.5, 1, 2 s)
# Bytes per second a busy server is given to store a `_bulk_docs` body before its answer is
# overdue: a 3-node cluster on a loaded machine took 14 s for 9 MB; with the bare `timeout`,
# ten robots draining their spools at once each gave up before the answer came, and sent the
# same batch again, for minutes.
_LOADED_SERVER_RATE = 500_000
#: Seconds attachments go as base64 inside `_bulk_docs` after a multipart write got no answer.
MULTIPART_PAUSE = 600.0
_INLINE = "inline"  # a batch item's kind: a document with base64 attachments (see `_encode`)


@register_backend("http", "https")
class CouchStore(MessageStore):
    """Messages in a CouchDB database (URL http(s)://[user:pass@]host:port/dbname)."""

    backend = "couchdb"
    backend_title = "CouchDB"
    chunks = True   # stores ros_mongo.storage.chunks.ChunkRecord (chunked topics)

    def __init__(self, url: str, *, timeout: float = 30.0, page_size: int = 200,
                 tls_ca_file: Optional[str] = None, tls_cert_file: Optional[str] = None,
                 tls_key_file: Optional[str] = None, tls_verify: bool = True,
                 client: Optional[CouchClient] = None, **options):
        super().__init__(url, **options)
        self.client = client or CouchClient(url, timeout=timeout, tls_ca_file=tls_ca_file,
                                            tls_cert_file=tls_cert_file, tls_key_file=tls_key_file,
                                            tls_verify=tls_verify)
        self.db_name = self.client.name
        if self.db_name[0] not in "abcdefghijklmnopqrstuvwxyz" or not set(self.db_name) <= _DB_NAME_CHARS:
            raise StoreError(f"bad CouchDB database name {self.db_name!r}: lowercase letters, digits "
                             f"and _$()+-/ only, starting with a letter")
        self.timeout = self.client.timeout
        self.page_size = int(page_size)
        self.indexed: Optional[bool] = None  # whether the Mango indexes exist (None: not known yet)
        self._multipart_off_until = 0.0  # monotonic time until which attachments go as base64

    # -- HTTP (ros_mongo.storage.couch_client: one client, one error mapping) ---------------------------
    def _request(self, method: str, path: str, *, ok=(200, 201, 202), **kwargs) -> requests.Response:
        """One request; any answer outside `ok` raises per the taxonomy in the module docstring."""
        return self.client.request(method, path, ok=ok, **kwargs)

    def _json(self, method: str, path: str, **kwargs):
        """The JSON body of a successful request (a body that is not JSON: StoreUnavailable)."""
        return self.client.json(method, path, **kwargs)

    def _read(self, method: str, path: str, **kwargs):
        """`_json` for reads, retried with backoff while the answer is "retry later" (a truncated
        body is retried, never taken for the end)."""
        for attempt in range(_READ_RETRIES):
            try:
                return self._json(method, path, **kwargs)
            except StoreUnavailable:
                if attempt == _READ_RETRIES - 1:
                    raise
                time.sleep(0.5 * 2 ** attempt)
        raise AssertionError("unreachable")

    def ping(self) -> None:
        self._request("GET", "", ok=(200, 404))

    def _setup(self) -> None:
        response = self._request("GET", "", ok=(200, 404))
        if response.status_code == 404:
            try:
                self._request("PUT", "", ok=(201, 202, 412))
            except StoreRefused as err:
                raise StoreRefused(f"CouchDB database {self.db_name} does not exist and this account "
                                   f"may not create it (an admin creates it, e.g. ros_mongo_bag setup): "
                                   f"{err}") from None
        if self.indexed is None:
            self.ensure_indexes()

    def ensure_indexes(self) -> bool:
        """Create the Mango indexes (design documents) unless they exist; tolerant of another
        robot creating them at the same time; False (with one warning) when the account may not."""
        existing = {index.get("name") for index in self._json("GET", "/_index").get("indexes", [])}
        missing = [name for name in _INDEXES if name not in existing]
        for name in missing:
            body = {"index": {"fields": _INDEXES[name]}, "name": name, "ddoc": name, "type": "json"}
            try:
                self._request("POST", "/_index", json=body)
            except StoreRefused as err:
                log.warning("cannot create the Mango indexes of %s (%s): recording works; reads go "
                            "through _all_docs, slower, until an admin runs `ros_mongo_bag setup`",
                            self.url, err)
                self.indexed = False
                return False
            except StoreUnavailable as err:
                if "error_saving_ddoc" in str(err) and "conflict" in str(err):
                    continue  # another client created it at the same time
                raise
        self.indexed = True
        return True

    def close(self) -> None:
        self.client.close()

    # -- writing -----------------------------------------------------------------------------
    def _batch_item(self, record: MessageRecord) -> Tuple[Tuple[str, Optional[str], Tuple[bytes, ...]], int]:
        chunk = isinstance(record, ChunkRecord)
        blob = chunk or len(record.raw) > self.blob_threshold
        content_type, parts = self._encode(record, blob, chunk)
        return (record.id, content_type, parts), sum(len(part) for part in parts)

    def _encode(self, record: MessageRecord, blob: bool,
                chunk: bool = False) -> Tuple[Optional[str], Tuple[bytes, ...]]:
        """(None, the document's JSON) with its bytes inline as base64; when `blob` (always for a
        chunk: its messages' bytes, concatenated, and its decoded fields) the content type and
        parts of its `multipart/related` body (see `_put_blob`), or while multipart writes are
        off (`_put_blob`) `_INLINE` and the document with base64 attachments."""
        fields = None
        if chunk:  # the decoded fields as an attachment: the server does not parse them
            doc = chunk_doc(record)
            msgs = doc.pop("msgs")
            fields = _dumps(msgs) if any(m is not None for m in msgs) else None
            if fields is not None:
                doc["fields"] = "attachment"
        else:
            doc = message_doc(record)
        if not blob:  # SIMD base64: a tenth of binascii's CPU
            doc["raw"] = pybase64.b64encode(record.raw).decode("ascii")
        body = _dumps(doc)
        if body is None or len(body) > MAX_DOC_BYTES:
            doc["msg"], doc["fields_dropped"] = None, True
            body = _dumps(doc)
            if body is None or len(body) > MAX_DOC_BYTES:
                raise StoreError(f"message {record.id} on {record.topic} does not fit a CouchDB "
                                 f"document even without its fields")
        if not blob:
            return None, (body,)
        attachments = [("raw", record.raw)] + ([("fields", fields)] if fields is not None else [])
        if time.monotonic() < self._multipart_off_until:
            return _INLINE, inline_document(body, message_rev(record.id), attachments)
        return multipart_document(body, message_rev(record.id), attachments)

    def _write_batch(self, items: List[Tuple[str, Optional[str], Tuple[bytes, ...]]], errors: list, *,
                     look_up: bool = True) -> int:
        """Documents with inline bytes in one `_bulk_docs` (a conflict: stored by an earlier
        attempt), then each one with attachments in its own PUT (`_put_blob`); with `look_up`,
        those stored already (one `_all_docs` lookup) are left alone and not counted."""
        inline = [parts for _, content_type, parts in items if content_type is None]
        blobs = [item for item in items if item[1] is not None]
        stored = 0
        if inline:
            response = self._bulk(b'{"docs":[', inline)
            results = _bulk_results(response, self.url)
            written = [result.get("id") for result in results if "error" not in result]
            errors += [f"{result.get('id')}: {result['error']} {result.get('reason', '')}"
                       for result in results if "error" in result and result["error"] != "conflict"]
            if response.status_code == 202 and written:
                self._check_durable(written)
            stored += len(written)
        present = self._present([doc_id for doc_id, _, _ in blobs]) if look_up and blobs else set()
        todo = [item for item in blobs if item[0] not in present]
        as_json = [(doc_id, parts) for doc_id, kind, parts in todo if kind == _INLINE]
        if as_json:
            stored += self._write_inline_blobs(as_json, errors)
        for doc_id, kind, parts in todo:
            if kind != _INLINE:
                stored += self._put_blob(doc_id, kind, parts, errors)
        return stored

    def _write_inline_blobs(self, items: List[Tuple[str, Tuple[bytes, ...]]], errors: list) -> int:
        """Documents with base64 attachments in one `_bulk_docs` with `new_edits: false` (their
        revision given, as in `_put_blob`: a document stored already is left as it is)."""
        response = self._bulk(b'{"new_edits":false,"docs":[', [parts for _, parts in items])
        refused = set()
        for result in _bulk_results(response, self.url):  # new_edits false: only documents not written
            if "error" in result:
                refused.add(result.get("id"))
                errors.append(f"{result.get('id')}: {result['error']} {result.get('reason', '')}")
        written = [doc_id for doc_id, _ in items if doc_id not in refused]
        if response.status_code == 202 and written:
            self._check_durable(written)
        return len(written)

    def _put_blob(self, doc_id: str, content_type: str, parts: Tuple[bytes, ...], errors: list) -> int:
        """One document with its attachments: `PUT /db/<id>?new_edits=false` of its multipart body
        (its revision given: written once however often it is sent, see the module docstring).
        Refused on its own merits (400, 413): into `errors`, 0. No answer in time: multipart
        writes are off for `MULTIPART_PAUSE` seconds (an Apache CouchDB cluster with a node down
        never answers a multipart PUT: measured on 3.5, while `_bulk_docs` answers at once), and
        StoreUnavailable: the retry sends base64 attachments in `_bulk_docs`."""
        data = b"".join(parts)
        try:
            # the server answers once it has stored the attachments: its time grows with the body
            response = self._request("PUT", "/" + quote(doc_id, safe=""), ok=(201, 202, 400, 413),
                                     params={"new_edits": "false"}, data=data,
                                     headers={"Content-Type": content_type},
                                     timeout=(self.timeout, self.timeout + len(data) / _LOADED_SERVER_RATE))
        except StoreUnavailable as err:
            if isinstance(err.__cause__, requests.Timeout):
                self._multipart_off_until = time.monotonic() + MULTIPART_PAUSE
                log.warning("%s did not answer a multipart write in time: attachments go as base64 in "
                            "_bulk_docs for %.0f s", self.url, MULTIPART_PAUSE)
            raise
        if response.status_code in (400, 413):
            errors.append(f"{doc_id}: {self.client.error(response, 'PUT')}")
            return 0
        if response.status_code == 202:
            self._check_durable([doc_id])
        return 1

    def _bulk(self, head: bytes, bodies: List[Tuple[bytes, ...]]) -> requests.Response:
        """POST `_bulk_docs`: `head` (up to the docs array's "["), the documents' parts, "]}"."""
        pieces = [head]
        for index, parts in enumerate(bodies):
            if index:
                pieces.append(b",")
            pieces.extend(parts)
        pieces.append(b"]}")
        data = b"".join(pieces)
        try:
            # the server answers once it has stored every document: its time grows with the body
            return self._request("POST", "/_bulk_docs", data=data,
                                 headers={"Content-Type": "application/json"},
                                 timeout=(self.timeout, self.timeout + len(data) / _LOADED_SERVER_RATE))
        except StoreError as err:
            if type(err) is StoreError and "answered 400" in str(err):  # the batch is malformed
                raise BatchTooLarge(str(err)) from None
            raise

    def _present(self, ids: List[str]) -> set:
        """Which of `ids` the database holds (deleted ones included: they were stored)."""
        rows = self._json("POST", "/_all_docs", json={"keys": ids}).get("rows", [])
        return {row.get("key") for row in rows if isinstance(row, dict) and "error" not in row}

    def _check_durable(self, ids: List[str]) -> None:
        """After a 202 (accepted without the write quorum): every document must be readable."""
        rows = self._json("POST", "/_all_docs", json={"keys": ids}).get("rows", [])
        missing = [row.get("key") for row in rows if "error" in row or row.get("value", {}).get("deleted")]
        if missing or len(rows) != len(ids):
            raise StoreUnavailable(f"CouchDB at {self.url} accepted a write without its quorum (202) "
                                   f"and {len(missing) or len(ids) - len(rows)} documents are not "
                                   f"readable yet")

    def _put_topic_doc(self, info: TopicInfo) -> None:
        self._request("PUT", "/" + quote(info.id, safe=""), json=topic_doc(info), ok=(201, 202, 409))

    # -- reading -----------------------------------------------------------------------------
    def _topic_docs(self) -> List[dict]:
        params = {"startkey": '"topic-"', "endkey": '"topic-\ufff0"', "include_docs": "true"}
        rows = self._read("GET", "/_all_docs", params=params)["rows"]
        return [row["doc"] for row in rows if row.get("doc")]

    def _docs(self, query: Query, newest_first: bool, limit: Optional[int],
              decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        fields = None if decoded else list(META_KEYS) + ["raw"]
        return self._merged(query, newest_first, limit, fields, True, decoded)

    def _count(self, query: Query) -> int:
        return sum(1 for _ in self._merged(query, False, None, ["_id", "receive_time"], False, False))

    def _merged(self, query: Query, newest_first: bool, limit: Optional[int], fields: Optional[List[str]],
                with_bytes: bool, decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        """One sorted stream per topic (each uses the topic+time index), chunks expanded into their
        messages (ros_mongo.storage.chunks), merged by time: (message document, its bytes when inline or
        `with_bytes` for a chunk's; a chunk's decoded fields when `decoded`)."""
        if limit == 0:
            return iter(())
        topics = query.topics or [None]
        # a chunk starts up to CHUNK_SPAN before the messages it holds; messages outside the range
        # and chunk messages failing a field condition are left out in `_messages`
        wide = query if query.start_time is None else dataclasses.replace(
            query, start_time=query.start_time - CHUNK_SPAN)
        exact = query.start_time is None and not query.fields  # every document yields a match
        if fields is not None:
            fields = sorted(set(fields) | set(CHUNK_KEYS) | {"_id", "receive_time"})
        streams = [self._messages(self._stream(wide, topic, newest_first, limit if exact else None, fields),
                                  query, newest_first, with_bytes, decoded) for topic in topics]
        merged = streams[0] if len(streams) == 1 else heapq.merge(
            *streams, key=lambda m: (m[0]["receive_time"], m[0]["_id"]), reverse=newest_first)
        return merged if limit is None else take(merged, limit)

    def _messages(self, docs: Iterator[dict], query: Query, newest_first: bool, with_bytes: bool,
                  decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        """Documents of one sorted stream as (message document, bytes), chunks expanded."""
        match = field_matcher(query)

        def items():
            for doc in docs:
                if doc.get("kind") == "chunk":
                    raw = self._load_blob(doc["_id"]) if with_bytes else None
                    msgs = self.chunk_fields(doc) if decoded or query.fields else None
                    yield doc, [(m, b) for m, b in expand(doc, raw, msgs) if match(m)]
                else:
                    yield doc, (pybase64.b64decode(doc["raw"]) if doc.get("raw") is not None else None)
        low, high = query.start_time, query.end_time
        for doc, raw in sorted_messages(items(), newest_first):
            time_ = doc["receive_time"]
            if (low is None or time_ >= low) and (high is None or time_ <= high):
                yield doc, raw

    def _stream(self, query: Query, topic: Optional[str], newest_first: bool, limit: Optional[int],
                fields: Optional[List[str]]) -> Iterator[dict]:
        base = _selector(query, topic)
        if self.indexed is None:
            self._check_indexes()
        if not self.indexed:
            return self._by_id(query, base, newest_first, limit, fields)
        direction = "desc" if newest_first else "asc"
        sort = [{"topic": direction}, {"receive_time": direction}] if topic else [{"receive_time": direction}]
        page = Pager(self._find, base, sort, fields, self.page_size, newest_first)
        if set(base) <= {"topic"}:  # the index answers the whole selector: page by cursor
            return page.range(query.start_time, query.end_time, limit)
        # Other conditions are filtered after the index lookup (by pouchdb-server over the whole
        # remaining range), so read in time windows that adapt to the data's density.
        return page.windows(self._time_bounds(topic, query), limit)

    def _time_bounds(self, topic: Optional[str], query: Query) -> Optional[Tuple[float, float]]:
        selector: Dict[str, object] = {"topic": topic} if topic else {}
        ends = []
        for direction, given in (("asc", query.start_time), ("desc", query.end_time)):
            if given is not None:
                ends.append(given)
                continue
            sort = [{"topic": direction}, {"receive_time": direction}] if topic else \
                [{"receive_time": direction}]
            docs = self._find({"selector": dict(selector, receive_time={"$gte": -1e300}), "sort": sort,
                               "limit": 1, "fields": ["receive_time"]})
            if not docs:
                return None
            ends.append(docs[0]["receive_time"])
        return (ends[0], ends[1]) if ends[0] <= ends[1] else None

    def _find(self, body: dict) -> List[dict]:
        try:
            return self._read("POST", "/_find", json=body)["docs"]
        except StoreError as err:
            if type(err) is StoreError and "answered 400" in str(err):
                raise QueryError(f"CouchDB rejected the query: {err}") from None
            raise

    def _check_indexes(self) -> None:
        """Whether the Mango indexes exist (reads without them take the slower `_by_id` path)."""
        existing = {index.get("name") for index in self._read("GET", "/_index").get("indexes", [])}
        self.indexed = all(name in existing for name in _INDEXES)
        if not self.indexed:
            log.warning("%s has no Mango indexes (an admin creates them with `ros_mongo_bag setup`): "
                        "reading in id order through _all_docs, slower", self.url)

    def _by_id(self, query: Query, base: dict, newest_first: bool, limit: Optional[int],
               fields: Optional[List[str]]) -> Iterator[dict]:
        """Without indexes: message ids in receive-time order from `_all_docs` ranges, each page
        matched by `_find` without sort (the server's own matching), sorted here."""
        selector = dict(base)
        selector["receive_time"] = {"$gte": -1e300 if query.start_time is None else query.start_time}
        if query.end_time is not None:
            selector["receive_time"]["$lte"] = query.end_time
        low = id_bound(query.start_time, -1, "") if query.start_time is not None else "0"
        high = id_bound(query.end_time, 1, "\ufff0") if query.end_time is not None else "9\ufff0"
        if fields:
            fields = sorted(set(fields) | {"_id", "receive_time"})
        page = max(self.page_size, 500)
        start, skip, yielded = (high, low) if newest_first else (low, high), 0, 0
        key, end = start
        while limit is None or yielded < limit:
            params = {"startkey": json.dumps(key), "endkey": json.dumps(end), "limit": page, "skip": skip}
            if newest_first:
                params["descending"] = "true"
            rows = self._read("GET", "/_all_docs", params=params)["rows"]
            ids = [row["id"] for row in rows]
            if not ids:
                return
            body = {"selector": {"$and": [selector, {"_id": {"$in": ids}}]}, "limit": len(ids)}
            if fields:
                body["fields"] = fields
            docs = sorted(self._find(body), key=lambda d: (d["receive_time"], d["_id"]),
                          reverse=newest_first)
            for doc in docs:
                if limit is not None and yielded >= limit:
                    return
                yielded += 1
                yield doc
            if len(rows) < page:
                return
            key, skip = ids[-1], 1

    def _load_blob(self, message_id: str, name: str = "raw") -> bytes:
        response = self._request("GET", f"/{quote(message_id, safe='')}/{name}", ok=(200, 404),
                                 headers={"Accept": "application/octet-stream"})
        if response.status_code == 404:
            raise StoreError(f"message {message_id} has no stored {'bytes' if name == 'raw' else name} "
                             f"in {self.url}")
        return response.content

    def chunk_fields(self, doc: dict) -> Optional[list]:
        """The decoded fields of a chunk's messages (None when it stores none)."""
        if doc.get("fields") != "attachment":
            return None
        msgs = orjson.loads(self._load_blob(doc["_id"], "fields"))
        if not isinstance(msgs, list) or len(msgs) != doc["count"]:
            raise StoreError(f"chunk {doc['_id']} in {self.url} holds unreadable fields")
        return msgs


def _selector(query: Query, topic: Optional[str]) -> Dict[str, object]:
    """The query's selector for one topic's stream (or all topics), without the time range: the
    pager adds that. Chunks are selected by their metadata alone (their messages' fields are
    checked message by message: `field_matcher`)."""
    one_topic = dataclasses.replace(query, topics=[topic] if topic else None, start_time=None,
                                    end_time=None)
    selector = to_selector(query_conditions(one_topic))
    if "$or" in selector:  # conditions on decoded fields, as [{"$and": [...]}]
        selector["$or"] = selector["$or"] + [{"kind": "chunk"}]
    return selector


def field_matcher(query: Query):
    """doc -> bool: whether a message document (one of a chunk, expanded) meets the query's
    conditions on decoded fields, as the server answers the same selector for message documents."""
    conditions = [c for c in query_conditions(query) if c.field.startswith("msg.")]
    if not conditions:
        return lambda doc: True
    return compile_selector(to_selector(conditions))


def message_rev(doc_id: str) -> str:
    """The revision a message document is written with: "1-" and 32 hex digits derived from its id
    (a message id names one message, so every writer of it gives the same revision)."""
    return "1-" + hashlib.blake2b(doc_id.encode("utf-8"), digest_size=16).hexdigest()


def _bulk_results(response: requests.Response, url: str) -> List[dict]:
    """The per-document results of a `_bulk_docs` answer (StoreUnavailable when it is not JSON or
    not a list; TypeError for an item that is not an object: a writer restart, not a retry)."""
    try:
        results = response.json()
    except ValueError:
        raise StoreUnavailable(f"CouchDB at {url} answered _bulk_docs with {response.status_code} and a "
                               f"body that is not JSON") from None
    if not isinstance(results, list):
        raise StoreUnavailable(f"CouchDB at {url} answered _bulk_docs with {results!r:.200}")
    for result in results:
        if not isinstance(result, dict):
            raise TypeError(f"CouchDB answered _bulk_docs with an item of an unexpected shape: "
                            f"{result!r:.200}")
    return results


def _dumps(doc: dict) -> Optional[bytes]:
    """Compact JSON (orjson: a fifth of the json module's CPU for the decoded fields); None for a
    document that JSON cannot hold."""
    try:
        return orjson.dumps(doc)
    except TypeError:  # orjson.JSONEncodeError: an integer beyond 64 bits, a key that is no string
        return None
