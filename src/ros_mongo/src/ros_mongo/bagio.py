"""Bags to the database and back, losslessly: topics, types, md5sums, definitions, connection
headers (latching, callerid), receive times and the exact serialized bytes.

Importing decodes each message for the queryable fields on the main thread while a writer thread
sends the previous batch to the database (one bulk request per batch).
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

from ros_mongo.errors import BagError, StoreError, UnknownTypeError
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo, make_record
from ros_mongo.store import MessageStore

__all__ = ["import_bag", "export_bag", "TransferResult"]


@dataclass
class TransferResult:
    messages: int
    bytes: int
    seconds: float

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
               batch_size: int = 500, progress: bool = True) -> TransferResult:
    """Store every message of the bag (or of `topics`); the receive time is the bag time.

    Ids derive from the session id (default: the bag's file name) and the message's place in the
    bag, so importing the same bag again with the same session id stores nothing twice.
    """
    import rosbag
    from tqdm import tqdm

    session_id = session_id or Path(path).stem
    started, count, size = time.monotonic(), 0, 0
    writer = _BatchWriter(store)
    with _open_bag(path) as bag:
        total = bag.get_message_count(topic_filters=list(topics) if topics else None)
        bar = tqdm(total=total, unit="msg", desc=f"import {Path(path).name}", disable=not progress)
        batch: List[Union[MessageRecord, TopicInfo]] = []
        seen: Dict[Tuple[str, str, str], TopicInfo] = {}
        try:
            for topic, raw, stamp, header in bag.read_messages(topics=topics, raw=True,
                                                               return_connection_header=True):
                msg_type, data, md5sum, _pos, pytype = raw
                key = (topic, msg_type, md5sum)
                if key not in seen:
                    seen[key] = _topic_info(topic, header)
                    batch.append(seen[key])
                record_id = _bag_id(session_id, topic, count, stamp)
                batch.append(_record(topic, pytype, msg_type, md5sum, data, stamp, record_id, tags,
                                     session_id, robot_id, store.max_array_len))
                count += 1
                size += len(data)
                if count % batch_size == 0:
                    writer.put(batch)
                    batch = []
                    bar.update(batch_size)
            writer.put(batch)
            bar.update(count % batch_size)
        except (rosbag.ROSBagException, OSError) as err:
            raise BagError(f"cannot read bag {path}: {err}") from None
        finally:
            writer.close()
            bar.close()
    return TransferResult(count, size, time.monotonic() - started)


def _topic_info(topic: str, header: Dict[str, bytes]) -> TopicInfo:
    def text(key: str) -> str:
        value = header.get(key, b"")
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
    return TopicInfo(topic, text("type"), text("md5sum"), text("message_definition"),
                     text("latching") == "1", text("callerid"))


def _bag_id(session_id: str, topic: str, index: int, stamp: genpy.Time) -> str:
    token = hashlib.sha1(f"{session_id}\n{topic}\n{index}".encode()).hexdigest()[:12]
    return f"{stamp.secs * 1000000000 + stamp.nsecs:019d}-{token}"


def _record(topic, pytype, msg_type, md5sum, data, stamp, record_id, tags, session_id, robot_id,
            max_array_len) -> MessageRecord:
    if pytype is not None and pytype._md5sum == md5sum:
        return make_record(topic, pytype, data, receive=stamp, tags=tags, session_id=session_id,
                           robot_id=robot_id, record_id=record_id, max_array_len=max_array_len)
    return MessageRecord(record_id, topic, msg_type, md5sum, bytes(data), stamp.secs, stamp.nsecs,
                         tags=list(tags), session_id=session_id, robot_id=robot_id)


class _BatchWriter:
    """Writes batches on a thread while the caller prepares the next one."""

    def __init__(self, store: MessageStore):
        self.store = store
        self.queue: queue.Queue = queue.Queue(maxsize=3)
        self.error: Optional[BaseException] = None
        self.thread = threading.Thread(target=self._run, name="ros_mongo_import", daemon=True)
        self.thread.start()

    def put(self, batch: list) -> None:
        if self.error is not None:
            raise self.error
        if batch:
            self.queue.put(batch)

    def close(self) -> None:
        self.queue.put(None)
        self.thread.join()
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        while True:
            batch = self.queue.get()
            if batch is None:
                return
            if self.error is not None:
                continue
            try:
                for entry in batch:
                    if isinstance(entry, TopicInfo):
                        self.store.put_topic(entry)
                self.store.insert_records([e for e in batch if isinstance(e, MessageRecord)])
            except StoreError as err:
                self.error = err


def export_bag(store: MessageStore, query: Query, path: Union[str, Path], *, overwrite: bool = False,
               compression: str = "none", progress: bool = True) -> TransferResult:
    """Write the messages matching `query` to a new bag, in receive-time order."""
    from tqdm import tqdm

    path = Path(path)
    if path.exists() and not overwrite:
        raise BagError(f"bag {path} exists; choose another name or overwrite it explicitly")
    infos = {(i.topic, i.msg_type, i.md5sum): i for i in store.topics()}
    total = store.count(query)
    started, count, size = time.monotonic(), 0, 0
    partial = Path(str(path) + ".partial")
    bag = _open_bag(partial, "w", compression=compression)
    written: Dict[str, Tuple[str, str]] = {}
    try:
        with tqdm(total=total, unit="msg", desc=f"export {path.name}", disable=not progress) as bar:
            for stored in store.find(query):
                header, stub = _connection(infos, written, stored)
                bag.write(stored.topic, (stored.msg_type, stored.raw, stored.md5sum, None, stub),
                          t=stored.receive_stamp, raw=True, connection_header=header)
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


def _connection(infos, written, stored) -> Tuple[Dict[str, str], type]:
    key = (stored.topic, stored.msg_type, stored.md5sum)
    info = infos.get(key)
    if info is None:
        raise UnknownTypeError(f"no stored definition for {stored.msg_type} on {stored.topic}")
    earlier = written.setdefault(stored.topic, key[1:])
    if earlier != key[1:]:
        raise BagError(f"topic {stored.topic} holds both {earlier[0]} and {stored.msg_type}; a bag keeps "
                       f"one type per topic: export them separately with a type filter")
    header = {"topic": info.topic, "type": info.msg_type, "md5sum": info.md5sum,
              "message_definition": info.definition}
    if info.callerid:
        header["callerid"] = info.callerid
    header["latching"] = "1" if info.latching else "0"
    stub = type("StoredType", (), {"_type": info.msg_type, "_md5sum": info.md5sum,
                                   "_full_text": info.definition})
    return header, stub


def iter_bag(path: Union[str, Path]) -> Iterator[Tuple[str, bytes, genpy.Time, Dict[str, str]]]:
    """(topic, raw bytes, bag time, connection header) of every message (for checks and tests)."""
    with _open_bag(path) as bag:
        for topic, raw, stamp, header in bag.read_messages(raw=True, return_connection_header=True):
            yield topic, bytes(raw[1]), stamp, {k: (v.decode() if isinstance(v, bytes) else v)
                                                 for k, v in header.items()}

