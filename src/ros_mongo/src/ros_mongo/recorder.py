"""The recorder core (no ROS): serialized messages in, batched durable writes out.

`receive()` is called from subscriber callbacks and only enqueues; beyond `max_queue_bytes` (the
database is slower than the topics) messages go straight to the spool file instead, undecoded, and
are decoded and stored when the spool is drained: a message is dropped (and counted) only if the
spool cannot be written either. Writer threads (`writers`, default 2, so one encodes while the
other waits for the database) take batches (up to `batch_size` messages or `batch_period` seconds),
decode their fields and write each batch with one bulk request. While the database is unreachable
batches go to the spool file; the first writer probes the database every `retry_period` seconds and,
once it answers, drains the spool (each record once: ids dedupe).

What a SIGKILL can lose: only messages not yet written to the database or the spool, i.e. those
received during the last `batch_period` plus the writes in flight (bounded by `max_queue_bytes`).
Everything counted as stored or spooled survives (the spool is drained by the next recorder using it).
"""
import logging
import threading
import time
from collections import deque
from typing import Deque, Dict, List, Optional, Sequence, Tuple

import genpy

import ros_mongo.msgtypes as msgtypes
from ros_mongo.errors import SpoolError, StoreError, StoreUnavailable, UnknownTypeError
from ros_mongo.records import MessageRecord, TopicInfo, make_record, new_message_id
from ros_mongo.spool import Spool
from ros_mongo.store import MessageStore

__all__ = ["Recorder"]

log = logging.getLogger(__name__)
_Key = Tuple[str, str, str]


class Recorder:
    """Batches received messages into `store`, spooling to `spool` while the store is down.

    Args:
        store: an opened (or lazily connecting) MessageStore.
        spool: an opened Spool (leftovers from an earlier run are drained too).
        batch_size, batch_period: a batch is written when either is reached.
        max_queue_bytes: received bytes waiting in memory; more go to the spool.
        retry_period: seconds between probes of an unreachable database.
        writers: writer threads.
        session_id, robot_id, tags: stored with every message; topic_tags adds tags per topic.
    """

    def __init__(self, store: MessageStore, spool: Spool, *, batch_size: int = 500,
                 batch_period: float = 0.2, max_queue_bytes: int = 1 << 30, retry_period: float = 1.0,
                 writers: int = 2, session_id: Optional[str] = None, robot_id: Optional[str] = None,
                 tags: Sequence[str] = (), topic_tags: Optional[Dict[str, Sequence[str]]] = None):
        if batch_size < 1 or batch_period <= 0 or max_queue_bytes < 1 or retry_period <= 0 or writers < 1:
            raise ValueError("batch_size, batch_period, max_queue_bytes, retry_period and writers must be "
                             "positive")
        self.writers = int(writers)
        self.store, self.spool = store, spool
        self.batch_size, self.batch_period = int(batch_size), float(batch_period)
        self.max_queue_bytes, self.retry_period = int(max_queue_bytes), float(retry_period)
        self.session_id, self.robot_id, self.tags = session_id, robot_id, list(tags)
        self.topic_tags = {topic: list(t) for topic, t in (topic_tags or {}).items()}
        self._cond = threading.Condition()
        self._queue: Deque[tuple] = deque()
        self._queued_bytes = 0
        self._topics: Dict[_Key, TopicInfo] = {}
        self._classes: Dict[_Key, Optional[type]] = {}
        self._stopping = False
        self._threads: List[threading.Thread] = []
        self._count_lock = threading.Lock()
        self._spill_lock = threading.Lock()
        self._spilled_topics: set = set()
        self.db_ok, self._next_probe = True, 0.0
        self.received = self.stored = self.dropped = self.rejected = self.spooled = 0

    # -- called from subscriber threads -----------------------------------------------------------
    def receive(self, topic: str, raw: bytes, receive: genpy.Time, msg_type: str, md5sum: str,
                definition: str = "", latching: bool = False, callerid: str = "") -> bool:
        """Enqueue one serialized message (or spool it when the queue is full); False if dropped."""
        key = (topic, msg_type, md5sum)
        with self._cond:
            self.received += 1
            if key not in self._topics:
                info = TopicInfo(topic, msg_type, md5sum, definition, bool(latching), callerid)
                self._topics[key] = info
                self._queue.append((info,))
            if self._queued_bytes + len(raw) <= self.max_queue_bytes:
                self._queue.append((key, raw, receive.secs, receive.nsecs))
                self._queued_bytes += len(raw)
                if len(self._queue) >= self.batch_size:
                    self._cond.notify()
                return True
        return self._spill(key, raw, receive)

    def _spill(self, key: _Key, raw: bytes, receive: genpy.Time) -> bool:
        """Straight to the spool, undecoded (the fields are decoded when it is drained)."""
        record = MessageRecord(new_message_id(receive.secs, receive.nsecs), key[0], key[1], key[2], raw,
                               receive.secs, receive.nsecs, tags=self.tags + self.topic_tags.get(key[0], []),
                               session_id=self.session_id, robot_id=self.robot_id)
        with self._spill_lock:
            entries: list = [record]
            if (key, self.spool.generation) not in self._spilled_topics:
                entries.insert(0, self._topics[key])  # a later recorder may drain this spool
                self._spilled_topics.add((key, self.spool.generation))
            try:
                self.spool.append(entries)
            except SpoolError as err:
                self._add("dropped", 1)
                log.error("dropped a message on %s: queue full and %s", key[0], err)
                return False
        self._add("spooled", 1)
        return True

    def counts(self) -> Dict[str, int]:
        """received, stored, dropped, rejected, spooled (ever), spool_pending, queued."""
        return {"received": self.received, "stored": self.stored, "dropped": self.dropped,
                "rejected": self.rejected, "spooled": self.spooled,
                "spool_pending": self.spool.pending_records, "queued": len(self._queue)}

    # -- the writer ----------------------------------------------------------------------------
    def start(self) -> "Recorder":
        if self.spool.pending:
            log.info("spool %s holds %d messages from an earlier run; draining them",
                     self.spool.path, self.spool.pending_records)
        self._threads = [threading.Thread(target=self._run, args=(index,), name=f"ros_mongo_writer_{index}",
                                          daemon=True) for index in range(self.writers)]
        for thread in self._threads:
            thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> Dict[str, int]:
        """Write everything received (to the database, or the spool when it is down); drain the
        spool while time remains. Returns the final counts."""
        self._deadline = time.monotonic() + timeout
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        for thread in self._threads:
            thread.join(max(0.0, self._deadline + 5.0 - time.monotonic()))
        return self.counts()

    def _run(self, index: int) -> None:
        while True:
            items = self._take()
            if items:
                self._write(items)
            if index == 0:  # one thread probes and drains
                self._probe_and_drain()
            with self._cond:
                if self._stopping and not self._queue:
                    break
        if index == 0:
            for thread in self._threads[1:]:
                thread.join(max(0.0, self._deadline - time.monotonic()))
            while self.spool.pending and self.db_ok and time.monotonic() < self._deadline:
                self._drain_once()

    def _take(self) -> List[tuple]:
        with self._cond:
            deadline = time.monotonic() + self.batch_period
            while len(self._queue) < self.batch_size and not self._stopping:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            items, size, count = [], 0, 0
            while self._queue and count < self.batch_size and size < 32 * 1024 * 1024:
                item = self._queue.popleft()
                items.append(item)
                if len(item) > 1:
                    count += 1
                    size += len(item[1])
            self._queued_bytes -= size
            return items

    def _write(self, items: List[tuple]) -> None:
        entries = [item[0] if len(item) == 1 else self._record(*item) for item in items]
        if self.db_ok:
            try:
                self._store(entries)
                return
            except StoreUnavailable as err:
                self._went_down(err)
        self.spool.append(entries)
        self._add("spooled", sum(isinstance(e, MessageRecord) for e in entries))

    def _add(self, counter: str, value: int) -> None:
        with self._count_lock:
            setattr(self, counter, getattr(self, counter) + value)

    def _store(self, entries: list) -> None:
        records = [e for e in entries if isinstance(e, MessageRecord)]
        try:
            for entry in entries:
                if isinstance(entry, TopicInfo):
                    self.store.put_topic(entry)
            for key in {(r.topic, r.msg_type, r.md5sum) for r in records}:
                if key in self._topics:  # each topic's definition before its messages
                    self.store.put_topic(self._topics[key])
            self.store.insert_records(records)
            # counted once: a failed attempt that reached the database anyway was not counted
            self._add("stored", len(records))
        except StoreUnavailable:
            raise
        except StoreError as err:
            rejected = getattr(err, "rejected", len(records))
            self._add("rejected", rejected)
            self._add("stored", len(records) - rejected)
            log.error("database rejected %d messages: %s", rejected, err)

    def _record(self, key: _Key, raw: bytes, secs: int, nsecs: int) -> MessageRecord:
        topic = key[0]
        tags = self.tags + self.topic_tags.get(topic, [])
        cls = self._message_class(key)
        if cls is None:
            return MessageRecord(new_message_id(secs, nsecs), topic, key[1], key[2], raw, secs, nsecs,
                                 tags=tags, session_id=self.session_id, robot_id=self.robot_id)
        return make_record(topic, cls, raw, receive=genpy.Time(secs, nsecs), tags=tags,
                           session_id=self.session_id, robot_id=self.robot_id,
                           max_array_len=self.store.max_array_len)

    def _message_class(self, key: _Key) -> Optional[type]:
        if key not in self._classes:
            info = self._topics[key]
            try:
                self._classes[key] = msgtypes.message_class(info.msg_type, info.md5sum, info.definition)
            except UnknownTypeError as err:
                log.warning("storing %s without decoded fields: %s", info.topic, err)
                self._classes[key] = None
        return self._classes[key]

    def _complete(self, entries: list) -> None:
        """Decode the fields of spooled records that went to the spool undecoded."""
        for entry in entries:
            if isinstance(entry, TopicInfo):
                self._topics.setdefault((entry.topic, entry.msg_type, entry.md5sum), entry)
            elif entry.fields is None:
                key = (entry.topic, entry.msg_type, entry.md5sum)
                cls = self._message_class(key) if key in self._topics else None
                if cls is not None:
                    try:
                        message = msgtypes.decode(cls, entry.raw)
                    except UnknownTypeError:
                        continue
                    entry.header_stamp = msgtypes.header_stamp(message)
                    entry.fields = msgtypes.to_fields(message, self.store.max_array_len)

    def _went_down(self, err: StoreError) -> None:
        self.db_ok = False
        self._next_probe = time.monotonic() + self.retry_period
        log.warning("database unreachable (%s); spooling to %s", err, self.spool.path)

    def _probe_and_drain(self) -> None:
        if not self.db_ok:
            if time.monotonic() < self._next_probe:
                return
            try:
                self.store.connect()
                self.store.ping()
            except StoreError:
                self._next_probe = time.monotonic() + self.retry_period
                return
            self.db_ok = True
            log.info("database reachable again; draining %d spooled messages", self.spool.pending_records)
        if self.spool.pending:
            self._drain_once()

    def _drain_once(self) -> None:
        entries, offset = self.spool.read(max_entries=self.batch_size)
        records = sum(isinstance(e, MessageRecord) for e in entries)
        self._complete(entries)
        try:
            self._store(entries)
        except StoreUnavailable as err:
            self._went_down(err)
            return
        self.spool.commit(offset, records)
        if not self.spool.pending:
            log.info("spool drained")
