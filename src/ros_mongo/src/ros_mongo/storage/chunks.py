"""Chunked topics, their stored form (no ROS): many small messages of one topic as one document.

A document per message costs a CouchDB server far more than the message's bytes (about 0.5 ms of
its CPU for a 700-byte odometry message); a chunk holds up to `max_messages` consecutive messages
of one topic, publisher and robot received within `CHUNK_SPAN` seconds, as one document:

    _id = "<id of its first message>.chunk", kind="chunk", topic, type, md5sum, callerid,
    session_id, robot_id, tags, author (when set), receive_time / receive_secs / receive_nsecs
    (its first message's), receive_end (its last message's receive time), count,
    ids, secs, nsecs, header_stamps, sizes (one entry per message); the messages' exact bytes,
    concatenated in order, as the attachment `raw` (`sizes` cuts them apart), and their decoded
    fields (at the topic's ~decode level) as a JSON list in the attachment `fields`
    (`"fields": "attachment"`; a binary attachment the server stores without parsing it, which cut
    its CPU per odometry message by about half against the same fields inside the document).

Readers never see a chunk: `expand` turns one back into the message documents (and bytes) a
document per message would have been, with the same ids, so queries, replay, bag / MCAP export and
the changes follower keep message granularity and the exact bytes. What the server selects a chunk
by is its metadata (topic, type, tags, session, robot, author) and its first receive time; the
time range and conditions on decoded fields are checked by the reader, message by message, with
the selector the server gets for message documents (ros_mongo.storage.mango evaluates it as the server).

A chunk is formed once, in memory, before any write (ros_mongo.recording.chunker), and travels
as one unit through the writers, the spool and every retry: its id never changes, so it is stored
exactly once.
"""
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, List, Optional, Tuple

from ros_mongo.records import MessageRecord

__all__ = ["CHUNK_SPAN", "CHUNK_KEYS", "ChunkRecord", "chunk_doc", "expand", "message_count",
           "sorted_messages"]

#: Seconds of receive time one chunk covers at most (a reader widens a time range's start by it).
CHUNK_SPAN = 1.0
#: The keys of a chunk document a reader needs besides the message keys.
CHUNK_KEYS = ("kind", "count", "receive_end", "ids", "secs", "nsecs", "header_stamps", "sizes", "fields")
_SUFFIX = ".chunk"


@dataclass
class ChunkRecord:
    """Consecutive records of one topic key (topic, type, md5sum, publisher) stored as one document."""

    records: List[MessageRecord]

    @property
    def id(self) -> str:
        return self.records[0].id + _SUFFIX

    def __getattr__(self, name: str):  # topic, msg_type, md5sum, callerid, tags, ...: the first's
        if name == "records":
            raise AttributeError(name)
        return getattr(self.records[0], name)

    @property
    def count(self) -> int:
        return len(self.records)

    @property
    def raw(self) -> bytes:
        return b"".join(record.raw for record in self.records)


def message_count(entry: Any) -> int:
    """Messages an entry of the recorder or spool holds (a topic info: 0)."""
    if isinstance(entry, ChunkRecord):
        return entry.count
    return 1 if isinstance(entry, MessageRecord) else 0


def chunk_doc(chunk: ChunkRecord) -> dict:
    """The stored form of a chunk, without its bytes (the backend adds the attachment)."""
    records, first = chunk.records, chunk.records[0]
    doc = {"_id": chunk.id, "kind": "chunk", "topic": first.topic, "type": first.msg_type,
           "md5sum": first.md5sum, "receive_time": first.receive_time, "receive_secs": first.receive_secs,
           "receive_nsecs": first.receive_nsecs, "receive_end": records[-1].receive_time,
           "tags": list(first.tags), "session_id": first.session_id, "robot_id": first.robot_id,
           "callerid": first.callerid, "count": len(records), "size": sum(len(r.raw) for r in records),
           "ids": [r.id for r in records], "secs": [r.receive_secs for r in records],
           "nsecs": [r.receive_nsecs for r in records], "header_stamps": [r.header_stamp for r in records],
           "sizes": [len(r.raw) for r in records], "msgs": [r.fields for r in records]}
    if first.author:
        doc["author"] = first.author
    return doc


_SHARED = ("topic", "type", "md5sum", "tags", "session_id", "robot_id", "callerid", "author")


def expand(doc: dict, raw: Optional[bytes],
           msgs: Optional[list] = None) -> List[Tuple[dict, Optional[bytes]]]:
    """The message documents (and bytes, when `raw` holds the chunk's) a chunk document stands for,
    in order; `msgs`: the messages' decoded fields when the document does not hold them."""
    shared = {key: doc[key] for key in _SHARED if key in doc}
    shared["kind"] = "message"
    msgs = msgs or doc.get("msgs") or [None] * doc["count"]
    stamps = doc.get("header_stamps") or [None] * doc["count"]
    out, at = [], 0
    columns = zip(doc["ids"], doc["secs"], doc["nsecs"], doc["sizes"])
    for index, (doc_id, secs, nsecs, size) in enumerate(columns):
        message = dict(shared, _id=doc_id, receive_secs=secs, receive_nsecs=nsecs,
                       receive_time=secs + nsecs * 1e-9, header_stamp=stamps[index], size=size,
                       msg=msgs[index])
        out.append((message, None if raw is None else raw[at:at + size]))
        at += size
    if raw is not None and at != len(raw):
        raise ValueError(f"chunk {doc.get('_id')}: {len(raw)} bytes stored, its sizes add up to {at}")
    return out


def sorted_messages(items: Iterable[Tuple[dict, Any]], newest_first: bool) -> Iterator[Tuple[dict, Any]]:
    """Documents sorted by (receive_time, _id) of their first message, chunks among them, as one
    stream of message documents sorted by (receive_time, _id): `items` are (doc, payload) where a
    chunk's payload is its list of expanded (message, bytes) (a chunk's messages all come within
    `CHUNK_SPAN` s of its first one)."""
    import heapq
    pending: List[tuple] = []  # (key, message, bytes); key sorts ascending (negated when newest first)
    for doc, payload in items:
        start = doc["receive_time"]
        if newest_first:
            while pending and -pending[0][0][0] >= start + CHUNK_SPAN:
                _, message, raw = heapq.heappop(pending)
                yield message, raw
        else:
            while pending and pending[0][0][0] < start:
                _, message, raw = heapq.heappop(pending)
                yield message, raw
        if doc.get("kind") != "chunk":
            if not pending:
                yield doc, payload
                continue
            payload = [(doc, payload)]
        for message, raw in payload:
            key = ((-message["receive_time"], _Reverse(message["_id"])) if newest_first
                   else (message["receive_time"], message["_id"]))
            heapq.heappush(pending, (key, message, raw))
    while pending:
        _, message, raw = heapq.heappop(pending)
        yield message, raw


class _Reverse(str):
    """A string that sorts in reverse (ids of messages read newest first)."""

    __slots__ = ()

    def __lt__(self, other: str) -> bool:
        return str.__gt__(self, other)

    def __gt__(self, other: str) -> bool:
        return str.__lt__(self, other)
