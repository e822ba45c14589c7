"""Bags to the database and back, losslessly: topics, types, md5sums, definitions, connection
headers (latching, callerid), receive times and the exact serialized bytes.

Importing decodes each message for the queryable fields on the main thread while a writer thread
sends the previous batch to the database (one bulk request per batch).

Contracts:
- Memory is bounded by bytes, not message counts: a batch closes once it holds `batch_bytes`
  (default `BATCH_BYTES`, 16 MB) of serialized messages or `batch_size` messages, whichever comes
  first (a single larger message is a batch of its own), and at most three batches exist at once
  (one being filled, one queued, one being written), so an import holds about 3 x 16 MB of
  message bytes whatever the bag holds. `TransferResult.peak_batch_bytes` reports the most bytes
  held in batches at once.
- Import is idempotent: a message's id derives from the bag's fingerprint (start and end time,
  connections, message count; not its file name or path), its topic and its index within that
  topic, and the robot id, so importing a bag again, under another name, or first with --topics
  and then whole, stores nothing twice.
- Every connection keeps its own topic info (callerid, latching, definition; source: the robot id,
  else the session id), so a /tf with several publishers and several bags or robots in one
  database come back out exactly (export writes one bag connection per publisher and source).
"""
import hashlib
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple, Union

import genpy

from ros_mongo.backends.base import PreparedRecords
from ros_mongo.errors import BagError, StoreError, UnknownTypeError
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo, make_record, new_message_id
from ros_mongo.store import MessageStore

__all__ = ["import_bag", "export_bag", "TransferResult", "BATCH_BYTES", "BATCH_SIZE"]

#: Import batches close at this many bytes of serialized messages ...
BATCH_BYTES = 16 * 1024 * 1024
#: ... or at this many messages, whichever comes first.
BATCH_SIZE = 500


@dataclass
class TransferResult:
    messages: int
    bytes: int
    seconds: float
    peak_batch_bytes: int = 0

    @property
    def rate(self) -> float:
        return self.messages / self.seconds if self.seconds > 0 else 0.0

    @property
    def megabytes_per_second(self) -> float:
        return self.bytes / 1e6 / self.seconds if self.seconds > 0 else 0.0


def _open_bag(path: Union[str, Path], mode: str = "r", **options):
    import rosbag

    try:
        return rosbag.Bag(str(path), mode, **options)
    except (rosbag.ROSBagException, OSError, ValueError) as err:
        raise BagError(f"cannot {'read' if mode == 'r' else 'write'} bag {path}: {err}") from None


def import_bag(path: Union[str, Path], store: MessageStore, *, topics: Optional[Sequence[str]] = None,
               tags: Sequence[str] = (), session_id: Optional[str] = None, robot_id: Optional[str] = None,
               batch_size: int = BATCH_SIZE, batch_bytes: int = BATCH_BYTES,
               progress: bool = True) -> TransferResult:
    """Store every message of the bag (or of `topics`); the receive time is the bag time.

    Ids derive from the bag's fingerprint, the topic, the message's index within its topic and
    the robot id, so importing the same bag again stores nothing twice (see the module doc).
    """
    import rosbag
    from tqdm import tqdm

    if batch_size < 1 or batch_bytes < 1:
        raise BagError(f"batch_size and batch_bytes must be positive, got {batch_size!r}, {batch_bytes!r}")
    session_id = session_id or Path(path).stem
    started, count, size = time.monotonic(), 0, 0
    writer = _BatchWriter(store)
    with _open_bag(path) as bag:
        fingerprint = _fingerprint(bag)
        source = robot_id or session_id
        total = bag.get_message_count(topic_filters=list(topics) if topics else None)
        bar = tqdm(total=total, unit="msg", desc=f"import {Path(path).name}", disable=not progress)
        infos: List[TopicInfo] = []
        records: List[MessageRecord] = []
        batch_weight = 0
        seen: Dict[Tuple[str, str, str, str], TopicInfo] = {}
        per_topic: Dict[str, int] = {}
        try:
            for topic, raw, stamp, header in bag.read_messages(topics=topics, raw=True,
                                                               return_connection_header=True):
                msg_type, data, md5sum, _pos, pytype = raw
                info = _topic_info(topic, header, source)
                if info.key not in seen:
                    seen[info.key] = info
                    infos.append(info)
                index = per_topic.get(topic, 0)
                per_topic[topic] = index + 1
                record_id = _bag_id(fingerprint, topic, index, stamp, robot_id)
                records.append(_record(topic, pytype, msg_type, md5sum, data, stamp, record_id, tags,
                                       session_id, robot_id, store.max_array_len, info.callerid))
                count += 1
                size += len(data)
                batch_weight += len(data)
                if len(records) >= batch_size or batch_weight >= batch_bytes:
                    writer.put(infos, store.prepare_records(records), batch_weight)
                    bar.update(len(records))
                    infos, records, batch_weight = [], [], 0
            writer.put(infos, store.prepare_records(records), batch_weight)
            bar.update(len(records))
        except (rosbag.ROSBagException, OSError) as err:
            raise BagError(f"cannot read bag {path}: {err}") from None
        finally:
            writer.close()
            bar.close()
    return TransferResult(count, size, time.monotonic() - started, writer.peak_bytes)


def _fingerprint(bag) -> str:
    """What identifies a bag's content without reading it all: its time span, message count and
    connections (topic, type, md5sum, callerid)."""
    connections = sorted((c.topic, c.datatype, c.md5sum, _text(c.header, "callerid"))
                         for c in bag._get_connections())
    key = f"{bag.get_start_time()!r}\n{bag.get_end_time()!r}\n{bag.get_message_count()}\n{connections!r}"
    return hashlib.sha1(key.encode()).hexdigest()


def _text(header: Dict[str, bytes], key: str) -> str:
    value = header.get(key, b"")
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def _topic_info(topic: str, header: Dict[str, bytes], source: str) -> TopicInfo:
    return TopicInfo(topic, _text(header, "type"), _text(header, "md5sum"),
                     _text(header, "message_definition"), _text(header, "latching") == "1",
                     _text(header, "callerid"), source)


def _bag_id(fingerprint: str, topic: str, index: int, stamp: genpy.Time, robot_id: Optional[str]) -> str:
    token = hashlib.sha1(f"{fingerprint}\n{topic}\n{index}".encode()).hexdigest()[:12]
    return new_message_id(stamp.secs, stamp.nsecs, robot_id, token=token)


def _record(topic, pytype, msg_type, md5sum, data, stamp, record_id, tags, session_id, robot_id,
            max_array_len, callerid) -> MessageRecord:
    if pytype is not None and pytype._md5sum == md5sum:
        return make_record(topic, pytype, data, receive=stamp, tags=tags, session_id=session_id,
                           robot_id=robot_id, record_id=record_id, max_array_len=max_array_len,
                           callerid=callerid)
    return MessageRecord(record_id, topic, msg_type, md5sum, bytes(data), stamp.secs, stamp.nsecs,
                         tags=list(tags), session_id=session_id, robot_id=robot_id, callerid=callerid)


class _BatchWriter:
    """Writes batches on a thread while the caller decodes and encodes the next one (one batch
    queued, one being written; `peak_bytes`: the most message bytes held in batches at once,
    counting the one the caller filled). The caller encodes (`MessageStore.prepare_records`), so
    this thread only sends: the server is kept busy while the next batch is being prepared."""

    def __init__(self, store: MessageStore):
        self.store = store
        self.queue: queue.Queue = queue.Queue(maxsize=1)
        self.error: Optional[BaseException] = None
        self.held = 0
        self.peak_bytes = 0
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._run, name="ros_mongo_import", daemon=True)
        self.thread.start()

    def put(self, infos: List[TopicInfo], prepared: PreparedRecords, weight: int = 0) -> None:
        if self.error is not None:
            raise self.error
        if infos or prepared.records:
            with self._lock:  # the filled batch existed before it was queued
                self.held += weight
                self.peak_bytes = max(self.peak_bytes, self.held)
            self.queue.put((infos, prepared, weight))

    def close(self) -> None:
        self.queue.put(None)
        self.thread.join()
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            infos, prepared, weight = item
            try:
                if self.error is None:
                    for info in infos:
                        self.store.put_topic(info)
                    self.store.insert_prepared(prepared)
            except StoreError as err:
                self.error = err
            finally:
                del infos, prepared, item
                with self._lock:
                    self.held -= weight


def export_bag(store: MessageStore, query: Query, path: Union[str, Path], *, overwrite: bool = False,
               compression: str = "none", progress: bool = True) -> TransferResult:
    """Write the messages matching `query` to a new bag, in receive-time order, one connection per
    stored topic info (publisher and source). Memory: one message at a time (the store reads in
    pages of bounded size; bytes kept apart are fetched per message)."""
    from tqdm import tqdm

    path = Path(path)
    if path.exists() and not overwrite:
        raise BagError(f"bag {path} exists; choose another name or overwrite it explicitly")
    infos = _InfoIndex(store.topics())
    total = store.count(query)
    started, count, size = time.monotonic(), 0, 0
    partial = Path(str(path) + ".partial")
    bag = _open_bag(partial, "w", compression=compression)
    connections = _Connections(bag)
    try:
        with tqdm(total=total, unit="msg", desc=f"export {path.name}", disable=not progress) as bar:
            for stored in store.find(query):
                info = infos.lookup(stored)
                connections.write(info, stored)
                count += 1
                size += len(stored.raw)
                bar.update(1)
        bag.close()
        os.replace(partial, path)
    except BaseException:
        bag.close()
        partial.unlink(missing_ok=True)
        raise
    return TransferResult(count, size, time.monotonic() - started)


class _InfoIndex:
    """The topic info of a stored message: its exact (topic, type, md5sum, callerid, source),
    else the same publisher from any source, else any info of its topic and type."""

    def __init__(self, infos: Sequence[TopicInfo]):
        self.exact = {info.key: info for info in infos}
        self.by_caller: Dict[tuple, TopicInfo] = {}
        self.by_type: Dict[tuple, TopicInfo] = {}
        for info in sorted(infos, key=lambda i: i.key):
            self.by_caller.setdefault(info.key[:4], info)
            self.by_type.setdefault(info.key[:3], info)

    def lookup(self, stored) -> TopicInfo:
        base = (stored.topic, stored.msg_type, stored.md5sum)
        caller = base + (stored.callerid,)
        for source in (stored.robot_id, stored.session_id):
            if source and caller + (source,) in self.exact:
                return self.exact[caller + (source,)]
        info = self.exact.get(caller + ("",)) or self.by_caller.get(caller) or self.by_type.get(base)
        if info is None:
            raise UnknownTypeError(f"no stored definition for {stored.msg_type} on {stored.topic}")
        return info


class _Connections:
    """Writes messages with one bag connection per topic info. rosbag's Python writer keeps one
    connection per topic (the first header wins), so the writer's current connection of a topic
    is switched before each write (rosbag's `_topic_connections`, as in ROS Noetic's rosbag)."""

    def __init__(self, bag):
        self.bag = bag
        self.by_info: Dict[tuple, object] = {}
        self.types: Dict[str, Tuple[str, str]] = {}
        self.switch = isinstance(getattr(bag, "_topic_connections", None), dict)

    def write(self, info: TopicInfo, stored) -> None:
        earlier = self.types.setdefault(stored.topic, (info.msg_type, info.md5sum))
        if earlier != (info.msg_type, info.md5sum):
            raise BagError(f"topic {stored.topic} holds both {earlier[0]} and {stored.msg_type}; a bag "
                           f"keeps one type per topic: export them separately with a type filter")
        header = {"topic": info.topic, "type": info.msg_type, "md5sum": info.md5sum,
                  "message_definition": info.definition, "latching": "1" if info.latching else "0"}
        if info.callerid:
            header["callerid"] = info.callerid
        stub = type("StoredType", (), {"_type": info.msg_type, "_md5sum": info.md5sum,
                                       "_full_text": info.definition})
        if self.switch:
            connection = self.by_info.get(info.key)
            if connection is not None:
                self.bag._topic_connections[stored.topic] = connection
            else:
                self.bag._topic_connections.pop(stored.topic, None)
        self.bag.write(stored.topic, (stored.msg_type, stored.raw, stored.md5sum, None, stub),
                       t=stored.receive_stamp, raw=True, connection_header=header)
        if self.switch and info.key not in self.by_info:
            self.by_info[info.key] = self.bag._topic_connections[stored.topic]


def iter_bag(path: Union[str, Path]) -> Iterator[Tuple[str, bytes, genpy.Time, Dict[str, str]]]:
    """(topic, raw bytes, bag time, connection header) of every message (for checks and tests)."""
    with _open_bag(path) as bag:
        for topic, raw, stamp, header in bag.read_messages(raw=True, return_connection_header=True):
            yield topic, bytes(raw[1]), stamp, {k: (v.decode() if isinstance(v, bytes) else v)
                                                 for k, v in header.items()}

