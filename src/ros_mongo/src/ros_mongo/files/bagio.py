"""Log files (ROS 1 bags, MCAP) to the database and back, losslessly: topics, types, md5sums,
definitions, connection headers (latching, callerid), receive times and the exact serialized
bytes. The formats sit behind one reader / writer shape and a registry by name
(`ros_mongo.files.formats`): `ros_mongo.files.bagfile` (bags, also unindexed ones) and
`ros_mongo.files.mcapio` (MCAP, what Foxglove opens).

Importing decodes each message for the queryable fields on the main thread while a writer thread
sends the previous batch to the database (one bulk request per batch).

Contracts:
- Memory is bounded by bytes, not message counts: a batch closes once it holds `batch_bytes`
  (default `BATCH_BYTES`, 16 MB) of serialized messages or `batch_size` messages, whichever comes
  first (a single larger message is a batch of its own), and at most three batches exist at once
  (one being filled, one queued, one being written), so an import holds about 3 x 16 MB of
  message bytes whatever the file holds. `TransferResult.peak_batch_bytes` reports the most bytes
  held in batches at once.
- Import is idempotent: a message's id derives from the file's fingerprint (start and end time,
  connections, message count; not its file name, path or format), its topic and its index within
  that topic, and the robot id, so importing a file again, under another name, as the MCAP export
  of the same bag, or first with --topics and then whole, stores nothing twice.
- An unindexed bag (a crashed `rosbag record`) is imported as far as it is readable, as
  `rosbag reindex` would recover it; `TransferResult.recovery` says how much (the file is never
  modified).
- Every connection keeps its own topic info (callerid, latching, definition; source: the robot id,
  else the session id), so a /tf with several publishers and several bags or robots in one
  database come back out exactly (export writes one bag connection / MCAP channel per publisher
  and source).
"""
import hashlib
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Set, Tuple, Union

import genpy

from ros_mongo.errors import BagError, StoreError, UnknownTypeError
from ros_mongo.files import bagfile, mcapio  # noqa: F401 - they register the bag and MCAP formats
from ros_mongo.files.formats import Recovery, format_for_path, format_of_file, iter_file
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo, make_record, new_message_id
from ros_mongo.storage.base import PreparedRecords
from ros_mongo.storage.store import MessageStore

__all__ = ["import_file", "export_file", "iter_file", "import_bag", "export_bag", "iter_bag",
           "TransferResult", "BATCH_BYTES", "BATCH_SIZE"]

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
    recovery: Optional[Recovery] = None  # what an unindexed / unfinished file lost

    @property
    def rate(self) -> float:
        return self.messages / self.seconds if self.seconds > 0 else 0.0

    @property
    def megabytes_per_second(self) -> float:
        return self.bytes / 1e6 / self.seconds if self.seconds > 0 else 0.0


def import_file(path: Union[str, Path], store: MessageStore, *, topics: Optional[Sequence[str]] = None,
                tags: Sequence[str] = (), session_id: Optional[str] = None, robot_id: Optional[str] = None,
                batch_size: int = BATCH_SIZE, batch_bytes: int = BATCH_BYTES,
                progress: bool = True) -> TransferResult:
    """Store every message of the bag or MCAP file (or of `topics`); the receive time is the log
    time. The format is recognised by the file's first bytes.

    Ids derive from the file's fingerprint, the topic, the message's index within its topic and
    the robot id, so importing the same messages again stores nothing twice (see the module doc).
    """
    from tqdm import tqdm

    if batch_size < 1 or batch_bytes < 1:
        raise BagError(f"batch_size and batch_bytes must be positive, got {batch_size!r}, {batch_bytes!r}")
    session_id = session_id or _session_name(path)
    started, count, size = time.monotonic(), 0, 0
    writer = _BatchWriter(store)
    with format_of_file(path).reader(path, progress=progress) as reader:
        bar = tqdm(total=reader.count(topics), unit="msg", desc=f"import {Path(path).name}",
                   disable=not progress)
        infos: List[TopicInfo] = []
        records: List[MessageRecord] = []
        batch_weight = 0
        try:
            for info, record in _records(reader, topics, store, tags, session_id, robot_id):
                if info is not None:
                    infos.append(info)
                records.append(record)
                count += 1
                size += len(record.raw)
                batch_weight += len(record.raw)
                if len(records) >= batch_size or batch_weight >= batch_bytes:
                    writer.put(infos, store.prepare_records(records), batch_weight)
                    bar.update(len(records))
                    infos, records, batch_weight = [], [], 0
            writer.put(infos, store.prepare_records(records), batch_weight)
            bar.update(len(records))
        finally:
            writer.close()
            bar.close()
    return TransferResult(count, size, time.monotonic() - started, writer.peak_bytes, reader.recovery)


def _records(reader, topics, store: MessageStore, tags, session_id: str,
             robot_id: Optional[str]) -> Iterator[Tuple[Optional[TopicInfo], MessageRecord]]:
    """(its topic info when first seen, else None; its record) for every message of `reader`,
    with the ids of the module doc."""
    source = robot_id or session_id
    seen: Set[tuple] = set()
    per_topic: Dict[str, int] = {}
    for message in reader.messages(topics):
        info = _topic_info(message.topic, message.header, source)
        first = info.key not in seen
        seen.add(info.key)
        index = per_topic.get(message.topic, 0)
        per_topic[message.topic] = index + 1
        record_id = _bag_id(reader.fingerprint, message.topic, index, message.stamp, robot_id)
        yield (info if first else None), _record(message, record_id, tags, session_id, robot_id,
                                                 store.max_array_len, info.callerid)


def _session_name(path: Union[str, Path]) -> str:
    """The default session id: the file name without its suffix (.bag, .bag.active, .mcap)."""
    name = Path(path).name
    if name.endswith(".active") and len(name) > len(".active"):
        name = name[:-len(".active")]
    return Path(name).stem


def _topic_info(topic: str, header: Dict[str, str], source: str) -> TopicInfo:
    return TopicInfo(topic, header.get("type", ""), header.get("md5sum", ""),
                     header.get("message_definition", ""), header.get("latching", "") == "1",
                     header.get("callerid", ""), source)


def _bag_id(fingerprint: str, topic: str, index: int, stamp: genpy.Time, robot_id: Optional[str]) -> str:
    token = hashlib.sha1(f"{fingerprint}\n{topic}\n{index}".encode()).hexdigest()[:12]
    return new_message_id(stamp.secs, stamp.nsecs, robot_id, token=token)


def _record(message, record_id, tags, session_id, robot_id, max_array_len, callerid) -> MessageRecord:
    pytype, stamp = message.pytype, message.stamp
    if pytype is not None and pytype._md5sum == message.md5sum:
        return make_record(message.topic, pytype, message.data, receive=stamp, tags=tags,
                           session_id=session_id, robot_id=robot_id, record_id=record_id,
                           max_array_len=max_array_len, callerid=callerid)
    return MessageRecord(record_id, message.topic, message.msg_type, message.md5sum, bytes(message.data),
                         stamp.secs, stamp.nsecs, tags=list(tags), session_id=session_id,
                         robot_id=robot_id, callerid=callerid)


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


def export_file(store: MessageStore, query: Query, path: Union[str, Path], *,
                file_format: Optional[str] = None, overwrite: bool = False, compression: str = "none",
                progress: bool = True) -> TransferResult:
    """Write the messages matching `query` to a new bag or MCAP file (`file_format` "bag" or
    "mcap"; default: by the suffix, .mcap or else a bag), in receive-time order, one connection /
    channel per stored topic info (publisher and source). Refuses to overwrite an existing file
    unless `overwrite`. Memory: one message at a time (the store reads in pages of bounded size;
    bytes kept apart are fetched per message)."""
    from tqdm import tqdm

    path = Path(path)
    writer = format_for_path(path, file_format).writer(path, overwrite=overwrite, compression=compression)
    infos = _InfoIndex(store.topics())
    total = store.count(query)
    started, count, size = time.monotonic(), 0, 0
    with writer, tqdm(total=total, unit="msg", desc=f"export {path.name}", disable=not progress) as bar:
        for stored in store.find(query):
            writer.write(infos.lookup(stored), stored)
            count += 1
            size += len(stored.raw)
            bar.update(1)
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


#: The names the bag-only versions had.
import_bag = import_file
export_bag = export_file
iter_bag = iter_file
