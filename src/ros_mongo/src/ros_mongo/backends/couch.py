"""CouchDB backend: a small layer over one requests.Session (see the README for why no client
library). Works with Apache CouchDB >= 2 and pouchdb-server.

Layout: one document per message (`kind: "message"`); serialized bytes up to the blob threshold
inline as base64 (`raw`), larger ones as the attachment `raw` (so the document body stays far below
CouchDB's 8,000,000-byte limit, which is also enforced here because pouchdb-server does not);
one document per topic and type (`kind: "topic"`, id `topic-<hash>`). Mango indexes on
(topic, receive_time) and (receive_time); reads page through `_find` sorted by receive time.
"""
import base64
import binascii
import dataclasses
import heapq
import json
import time
from typing import Dict, Iterator, List, Optional, Tuple
from urllib.parse import quote, unquote, urlsplit, urlunsplit

import requests

from ros_mongo.backends.base import MessageStore, register_backend
from ros_mongo.documents import META_KEYS, message_doc, query_conditions, to_selector, topic_doc
from ros_mongo.errors import QueryError, StoreError, StoreUnavailable
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo

__all__ = ["CouchStore", "MAX_DOC_BYTES"]

MAX_DOC_BYTES = 8_000_000
_INDEXES = {"ros_mongo_topic_time": ["topic", "receive_time"], "ros_mongo_time": ["receive_time"]}
_DB_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_$()+-/")


@register_backend("http", "https")
class CouchStore(MessageStore):
    """Messages in a CouchDB database (URL http(s)://[user:pass@]host:port/dbname)."""

    backend = "couchdb"
    backend_title = "CouchDB"

    def __init__(self, url: str, *, timeout: float = 30.0, page_size: int = 200, **options):
        super().__init__(url, **options)
        parts = urlsplit(url)
        self.db_name = unquote(parts.path.strip("/")) or "robot_data"
        if self.db_name[0] not in "abcdefghijklmnopqrstuvwxyz" or not set(self.db_name) <= _DB_NAME_CHARS:
            raise StoreError(f"bad CouchDB database name {self.db_name!r}: lowercase letters, digits "
                             f"and _$()+-/ only, starting with a letter")
        netloc = parts.hostname or "localhost"
        if parts.port:
            netloc = f"{netloc}:{parts.port}"
        self.server_url = urlunsplit((parts.scheme, netloc, "", "", ""))
        self.db_url = f"{self.server_url}/{quote(self.db_name, safe='')}"
        self.timeout = float(timeout)
        self.page_size = int(page_size)
        self.session = requests.Session()
        self.session.headers.update({"Accept": "application/json"})
        if parts.username:
            self.session.auth = (unquote(parts.username), unquote(parts.password or ""))

    # -- HTTP --------------------------------------------------------------------------------
    def _request(self, method: str, path: str, *, ok=(200, 201, 202), **kwargs) -> requests.Response:
        url = self.db_url + path
        try:
            response = self.session.request(method, url, timeout=self.timeout, **kwargs)
        except (requests.ConnectionError, requests.Timeout) as err:
            raise StoreUnavailable(f"CouchDB at {self.url} is unreachable: {type(err).__name__}") from err
        except requests.RequestException as err:
            raise StoreError(f"CouchDB request {method} {path or '/'} failed: {err}") from err
        if response.status_code in ok:
            return response
        reason = _reason(response)
        if response.status_code in (502, 503, 504):
            raise StoreUnavailable(f"CouchDB at {self.url} is unavailable ({response.status_code}: {reason})")
        if response.status_code in (401, 403):
            raise StoreError(f"CouchDB refused access to {self.url} ({response.status_code}: {reason})")
        raise StoreError(f"CouchDB {method} {path or '/'} answered {response.status_code}: {reason}")

    def ping(self) -> None:
        self._request("GET", "", ok=(200, 404))

    def _setup(self) -> None:
        response = self._request("GET", "", ok=(200, 404))
        if response.status_code == 404:
            self._request("PUT", "", ok=(201, 202, 412))
        for name, fields in _INDEXES.items():
            self._request("POST", "/_index", json={"index": {"fields": fields}, "name": name,
                                                     "ddoc": name, "type": "json"})

    def close(self) -> None:
        self.session.close()

    # -- writing -----------------------------------------------------------------------------
    def _batch_item(self, record: MessageRecord) -> Tuple[bytes, int]:
        body = self._encode(record)
        return body, len(body)

    def _encode(self, record: MessageRecord) -> bytes:
        doc = message_doc(record)
        blob = len(record.raw) > self.blob_threshold
        raw64 = binascii.b2a_base64(record.raw, newline=False)
        if not blob:
            doc["raw"] = raw64.decode("ascii")
        body = _dumps(doc)
        if body is None or len(body) > MAX_DOC_BYTES:
            doc["msg"], doc["fields_dropped"] = None, True
            body = _dumps(doc)
            if body is None or len(body) > MAX_DOC_BYTES:
                raise StoreError(f"message {record.id} on {record.topic} does not fit a CouchDB "
                                 f"document even without its fields")
        if blob:
            return b"".join((body[:-1], b',"_attachments":{"raw":{"content_type":"application/octet-stream",'
                             b'"data":"', raw64, b'"}}}'))
        return body

    def _write_batch(self, bodies: List[bytes], errors: list) -> int:
        payload = b"".join((b'{"docs":[', b",".join(bodies), b"]}"))
        response = self._request("POST", "/_bulk_docs", data=payload,
                                 headers={"Content-Type": "application/json"})
        stored = 0
        for result in response.json():
            if "error" not in result:
                stored += 1
            elif result["error"] != "conflict":  # conflict: stored by an earlier attempt
                errors.append(f"{result.get('id')}: {result['error']} {result.get('reason', '')}")
        return stored

    def _put_topic_doc(self, info: TopicInfo) -> None:
        self._request("PUT", "/" + quote(info.id, safe=""), json=topic_doc(info), ok=(201, 202, 409))

    # -- reading -----------------------------------------------------------------------------
    def _topic_docs(self) -> List[dict]:
        params = {"startkey": '"topic-"', "endkey": '"topic-\ufff0"', "include_docs": "true"}
        rows = self._request("GET", "/_all_docs", params=params).json()["rows"]
        return [row["doc"] for row in rows if row.get("doc")]

    def _docs(self, query: Query, newest_first: bool, limit: Optional[int],
              decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        docs = self._merged(query, newest_first, limit, None if decoded else list(META_KEYS) + ["raw"])
        return ((doc, base64.b64decode(doc["raw"]) if doc.get("raw") is not None else None)
                for doc in docs)

    def _count(self, query: Query) -> int:
        return sum(1 for _ in self._merged(query, False, None, ["_id", "receive_time"]))

    def _merged(self, query: Query, newest_first: bool, limit: Optional[int],
                fields: Optional[List[str]]) -> Iterator[dict]:
        """One sorted stream per topic (each uses the topic+time index), merged by time."""
        if limit == 0:
            return iter(())
        topics = query.topics or [None]
        streams = [self._stream(query, topic, newest_first, limit, fields) for topic in topics]
        if len(streams) == 1:
            return streams[0]
        merged = heapq.merge(*streams, key=lambda d: (d["receive_time"], d["_id"]), reverse=newest_first)
        return merged if limit is None else _take(merged, limit)

    def _stream(self, query: Query, topic: Optional[str], newest_first: bool, limit: Optional[int],
                fields: Optional[List[str]]) -> Iterator[dict]:
        base = _selector(query, topic)
        direction = "desc" if newest_first else "asc"
        sort = [{"topic": direction}, {"receive_time": direction}] if topic else [{"receive_time": direction}]
        page = _Pager(self._find, base, sort, fields, self.page_size, newest_first)
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
            return self._request("POST", "/_find", json=body).json()["docs"]
        except StoreUnavailable:
            raise
        except StoreError as err:
            if "answered 400" in str(err):
                raise QueryError(f"CouchDB rejected the query: {err}") from None
            raise

    def _load_blob(self, message_id: str) -> bytes:
        response = self._request("GET", f"/{quote(message_id, safe='')}/raw", ok=(200, 404),
                                 headers={"Accept": "application/octet-stream"})
        if response.status_code == 404:
            raise StoreError(f"message {message_id} has no stored bytes in {self.url}")
        return response.content


def _selector(query: Query, topic: Optional[str]) -> Dict[str, object]:
    """The query's selector for one topic's stream (or all topics), without the time range: the
    pager adds that."""
    one_topic = dataclasses.replace(query, topics=[topic] if topic else None, start_time=None,
                                    end_time=None)
    return to_selector(query_conditions(one_topic))


class _Pager:
    """Reads one sorted `_find` stream in pages (CouchDB has no server cursor for Mango)."""

    def __init__(self, find, base: dict, sort: list, fields: Optional[List[str]], page_size: int,
                 newest_first: bool):
        self.find, self.base, self.sort, self.fields = find, base, sort, fields
        self.page_size, self.newest_first = page_size, newest_first

    def range(self, low: Optional[float], high: Optional[float], limit: Optional[int], *,
              open_end: bool = False) -> Iterator[dict]:
        """Documents with low <= receive_time <= high (the far end excluded when `open_end`)."""
        cursor, same, yielded = None, 0, 0
        while True:
            want = self.page_size if limit is None else min(self.page_size, limit - yielded)
            if want <= 0:
                return
            body = {"selector": dict(self.base, receive_time=self._condition(low, high, cursor, open_end)),
                    "sort": self.sort, "limit": want, "skip": same}
            if self.fields:
                body["fields"] = self.fields
            docs = self.find(body)
            for doc in docs:
                if doc["receive_time"] == cursor:
                    same += 1
                else:
                    cursor, same = doc["receive_time"], 1
                yield doc
            yielded += len(docs)
            if len(docs) < want:
                return

    def _condition(self, low, high, cursor, open_end) -> Dict[str, float]:
        if cursor is not None:
            if self.newest_first:
                high = cursor
            else:
                low = cursor
        condition = {"$gte": -1e300 if low is None else low}
        if high is not None:
            condition["$lte"] = high
        if open_end and not self.newest_first and high is not None:
            condition["$lt"] = condition.pop("$lte")
        if open_end and self.newest_first and low is not None:
            condition["$gt"] = condition.pop("$gte")
        return condition

    def windows(self, bounds: Optional[Tuple[float, float]], limit: Optional[int]) -> Iterator[dict]:
        """Documents within `bounds`, read window by window; each window's span doubles while
        windows answer fast and halves when they are slow."""
        if bounds is None:
            return
        low, high = bounds
        span, yielded = 1.0, 0
        edge = high if self.newest_first else low
        while (edge >= low) if self.newest_first else (edge <= high):
            if self.newest_first:
                start, end, last = max(low, edge - span), edge, edge - span <= low
            else:
                start, end, last = edge, min(high, edge + span), edge + span >= high
            began = time.monotonic()
            for doc in self.range(start, end, None if limit is None else limit - yielded,
                                  open_end=not last):
                yielded += 1
                yield doc
            if last or (limit is not None and yielded >= limit):
                return
            edge = start if self.newest_first else end
            took = time.monotonic() - began
            span = span * 2 if took < 0.1 else span / 2 if took > 0.5 else span


def _take(items: Iterator[dict], limit: int) -> Iterator[dict]:
    for count, item in enumerate(items):
        if count >= limit:
            return
        yield item


def _dumps(doc: dict) -> Optional[bytes]:
    try:
        return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    except (ValueError, TypeError):
        return None


def _reason(response: requests.Response) -> str:
    try:
        data = response.json()
        return f"{data.get('error', '')}: {data.get('reason', '')}".strip(": ")
    except ValueError:
        return response.text[:200]
