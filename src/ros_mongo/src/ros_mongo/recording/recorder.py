"""The recorder core (no ROS): serialized messages in, batched durable writes out.

`receive()` is called from subscriber callbacks and only enqueues; beyond `max_queue_bytes` of
memory (payload plus a fixed per-message overhead, `ITEM_OVERHEAD`) messages go straight to the
spool file instead, undecoded, and are decoded and stored when the spool is drained. Writer threads
(`writers`, default 2, so one encodes while another waits for the database) take batches (up to
`batch_size` messages or `batch_period` seconds) and decode them in parallel, but write them strictly
in the order they were taken (a ticket per batch); while the spool holds anything, new batches are
appended behind it, so the database always holds a prefix of what went through the queue.

Errors (ros_mongo.errors): *retry later* (StoreUnavailable) and *operator must act* (StoreRefused,
or any other unexpected store error) keep every message: the batch goes to the spool, `fault` holds
the server's reason (reported as ERROR on /diagnostics by the node), and the first writer probes
every `retry_period` seconds (doubling up to 10x while it fails) and drains the spool once writes
work again. A draining batch that fails is never skipped: it stays in the spool. Documents refused
on their own merits (DocumentsRejected, after splitting) go to the quarantine file (counted
`rejected` and `quarantined`). A writer that fails unexpectedly (SpoolError, an answer of an
unexpected shape, a bug) spools its batch, reports the failure and is restarted (`writer_restarts`).

`dropped` counts a message only when memory and disk are both exhausted: the queue is full and the
spool refuses it (SpoolFull: size limit or minimum free space), or a quarantine write fails.

What a SIGKILL can lose: only messages not yet written to the database or the spool, i.e. those
received during the last `batch_period` (on chunked topics, ros_mongo.storage.chunks: the last chunk's
`CHUNK_SPAN` plus `batch_period`) plus the batches waiting for their turn to be written (bounded by
`max_queue_bytes`). Everything counted as stored or spooled survives (the spool is drained
by the next recorder using it). Per topic, the database plus the spool hold a gap-free prefix of the
received messages, except when the queue overflowed (spilled messages overtake queued ones) or the
disk was full (a batch that could not be spooled waits in memory and is written after later ones).
"""
import logging
import threading
import time
from collections import deque
from typing import Deque, Dict, List, Optional, Sequence, Tuple, Union

import genpy

from ros_mongo.errors import SpoolError, StoreError
from ros_mongo.messages.decoding import DecodePolicy
from ros_mongo.recording.bandwidth import Bandwidth
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.chunker import (
    ITEM_OVERHEAD,
    Chunker,
    ChunkPolicy,
    PendingChunk,
    item_cost,
    item_entry,
    item_messages,
)
from ros_mongo.recording.deferral import Deferral, DeferredPart
from ros_mongo.recording.events import EventRing
from ros_mongo.recording.quarantine import Quarantine
from ros_mongo.recording.record_builder import Key as _Key
from ros_mongo.recording.record_builder import RecordBuilder
from ros_mongo.recording.store_writer import StoreWriter
from ros_mongo.recording.tally import Tally
from ros_mongo.records import TopicInfo
from ros_mongo.storage.chunks import message_count
from ros_mongo.storage.store import MessageStore

__all__ = ["Recorder", "ITEM_OVERHEAD"]

log = logging.getLogger(__name__)

#: Bytes of a deferred part read per write while releasing it (small: live batches go between).
RELEASE_BYTES = 4 * 1024 * 1024
#: Seconds an idle writer sleeps (nothing queued, no chunk open) unless a message arrives: the
#: housekeeping period (event windows decided, deferred parts released, a failing store probed).
IDLE_PERIOD = 1.0


class Recorder:
    """Batches received messages into `store`, spooling to `spool` while the store is down.

    Args:
        store: an opened (or lazily connecting) MessageStore.
        spool: an opened BoundedSpool (leftovers from an earlier run are drained too; its policy
            says which topics lose their oldest messages when it is full).
        batch_size, batch_period: a batch is written when either is reached.
        max_queue_bytes: memory for received messages waiting (payload + ITEM_OVERHEAD each);
            more go to the spool.
        retry_period: seconds between probes of a failing database (doubling up to 10x).
        writers: writer threads.
        session_id, robot_id, tags, author: stored with every message; topic_tags adds tags per topic.
        quarantine_path: where refused documents go (default: the spool path + ".quarantine").
        decode: how much of each topic's messages is decoded into queryable fields
            (ros_mongo.messages.decoding; default: everything).
        chunks: which topics are stored as chunks (ros_mongo.storage.chunks; default: none), for stores
            that take them (CouchDB).
        deferral: the deferred parts of the spool (ros_mongo.recording.deferral; default: none):
            their topics go to their part at once and are written only while its condition holds,
            a batch at a time while fewer than a batch of live messages wait (live first).
        bandwidth: the upload cap (ros_mongo.recording.bandwidth; default: none): live writes
            first, released deferred parts with what live writes leave.
    """

    def __init__(self, store: MessageStore, spool: BoundedSpool, *, batch_size: int = 500,
                 batch_period: float = 0.2, max_queue_bytes: int = 1 << 30, retry_period: float = 1.0,
                 writers: int = 2, session_id: Optional[str] = None, robot_id: Optional[str] = None,
                 tags: Sequence[str] = (), topic_tags: Optional[Dict[str, Sequence[str]]] = None,
                 quarantine_path: Optional[str] = None, author: Optional[str] = None,
                 decode: Optional[DecodePolicy] = None, chunks: Optional[ChunkPolicy] = None,
                 deferral: Optional[Deferral] = None, bandwidth: Optional[Bandwidth] = None):
        if batch_size < 1 or batch_period <= 0 or max_queue_bytes < 1 or retry_period <= 0 or writers < 1:
            raise ValueError(f"batch_size, batch_period, max_queue_bytes, retry_period and writers must "
                             f"be positive, got {batch_size!r}, {batch_period!r}, {max_queue_bytes!r}, "
                             f"{retry_period!r}, {writers!r}")
        self.writers = int(writers)
        self.store, self.spool, self.deferral = store, spool, deferral
        self.bandwidth = bandwidth if bandwidth is not None and bandwidth.active else None
        self.quarantine = Quarantine(quarantine_path or str(spool.path) + ".quarantine",
                                     min_free_bytes=0)
        self.tally = Tally()
        self.batch_size, self.batch_period = int(batch_size), float(batch_period)
        self.max_queue_bytes, self.retry_period = int(max_queue_bytes), float(retry_period)
        self._cond = threading.Condition()
        self._queue: Deque[tuple] = deque()
        self._queued_bytes = 0
        self._queued_messages = 0   # in the queue or in open chunks
        self._topics: Dict[_Key, TopicInfo] = {}
        self.writer = StoreWriter(store, self._topics, self.tally, self.quarantine, self.bandwidth,
                                  self._drop)
        self.records = RecordBuilder(self._topics, decode=decode or DecodePolicy(), tags=tags,
                                     topic_tags=topic_tags, session_id=session_id, robot_id=robot_id,
                                     author=author, max_array_len=store.max_array_len)
        self.chunks = chunks if chunks is not None and chunks.active else None
        if self.chunks is not None and not getattr(store, "chunks", False):
            log.warning("%s stores no chunks: every message is stored as a document of its own",
                        store.backend_title)
            self.chunks = None
        self._chunker = Chunker(self.chunks.max_messages, self.chunks.period) if self.chunks else Chunker(1)
        self._stopping = False
        self._idle = 0          # writers sleeping with nothing queued (a message wakes one)
        self._deadline = float("inf")
        self._threads: List[threading.Thread] = []
        self._spill_lock = threading.Lock()
        self._order = threading.Condition()
        self._tickets = 0       # batches taken
        self._turn = 0          # the batch whose turn it is to be written
        self.db_ok, self._next_probe, self._failures = True, 0.0, 0
        self.fault = ""         # the current fault (the server's reason), "" when writes work
        self.last_fault = ""    # the latest fault, kept after it cleared

    # -- called from subscriber threads -----------------------------------------------------------
    def receive(self, topic: str, raw: bytes, receive: genpy.Time, msg_type: str, md5sum: str,
                definition: str = "", latching: bool = False, callerid: str = "") -> bool:
        """Enqueue one serialized message (or spool it when the queue is full); False if dropped."""
        key = (topic, msg_type, md5sum, callerid)
        cost = len(raw) + ITEM_OVERHEAD
        part = self.deferral.target_for(topic) if self.deferral is not None else None
        with self._cond:
            self.tally.counts["received"] += 1  # one key, only ever written under _cond
            if key not in self._topics:
                info = TopicInfo(topic, msg_type, md5sum, definition, bool(latching), callerid,
                                 self.records.robot_id or "")
                self._topics[key] = info
                self._queue.append((info,))
            if part is None and self._queued_bytes + cost <= self.max_queue_bytes:
                self._queued_bytes += cost
                self._queued_messages += 1
                stamp = receive.secs + receive.nsecs * 1e-9
                if self.chunks is not None and self.chunks.chunked(topic, stamp):
                    self._queue.extend(self._chunker.add(key, raw, receive.secs, receive.nsecs,
                                                         time.monotonic()))
                else:
                    self._queue.append((key, raw, receive.secs, receive.nsecs))
                if len(self._queue) >= self.batch_size or self._idle:
                    self._cond.notify()
                return True
        if part is not None:
            return self._defer(part, key, raw, receive)
        return self._spill(key, raw, receive)

    def _defer(self, part: Union[DeferredPart, EventRing], key: _Key, raw: bytes,
               receive: genpy.Time) -> bool:
        """Into its deferred part or event ring, undecoded (decoded when released)."""
        record = self.records.raw(key, raw, receive.secs, receive.nsecs)
        try:
            part.append(record, self._topics)
        except SpoolError as err:
            self._drop({key[0]: 1}, f"it cannot be kept on the robot: {err}")
            return False
        self._add("deferred", 1)
        return True

    def _spill(self, key: _Key, raw: bytes, receive: genpy.Time) -> bool:
        """Straight to the spool, undecoded (the fields are decoded when it is drained)."""
        record = self.records.raw(key, raw, receive.secs, receive.nsecs)
        with self._spill_lock:
            try:
                self.spool.append([record], self._topics)
            except SpoolError as err:
                self._drop({key[0]: 1}, f"queue full and {err}")
                return False
        self._add("spooled", 1)
        return True

    def counts(self) -> Dict[str, int]:
        """received, stored, dropped (by the recorder when memory and spool were both exhausted,
        plus by the spool's policy when full), rejected, quarantined, spooled (ever), spool_pending,
        queued, queued_bytes, writer_restarts."""
        counts = self.tally.snapshot()[0]
        counts["dropped"] += self.spool.dropped_total()
        counts.update(spool_pending=self.spool.pending_records, queued=self._queued_messages,
                      queued_bytes=self._queued_bytes)
        if self.deferral is not None:
            counts["dropped"] += sum(self.deferral.dropped().values())
            counts["deferred_pending"] = self.deferral.pending_records()
            counts["recycled"] = sum(self.deferral.recycled().values())
            counts["event_ring"] = sum(r.pending_records() for r in self.deferral.rings.values())
        return counts

    def dropped_by_topic(self) -> Dict[str, int]:
        """Messages dropped per topic (memory and spool exhausted, or the spool's policy)."""
        dropped = self.tally.snapshot()[1]
        policy_drops = [self.spool.dropped] + ([self.deferral.dropped()] if self.deferral else [])
        for counts in policy_drops:
            for topic, count in dict(counts).items():
                dropped[topic] = dropped.get(topic, 0) + count
        return dropped

    def drop_reasons(self) -> Dict[str, str]:
        """The latest reason per topic that lost messages."""
        reasons = self.tally.snapshot()[2]
        for topic in self.dropped_by_topic():
            reasons.setdefault(topic, "spool full: the oldest messages of droppable topics go first")
        return reasons

    def uploaded_by_topic(self) -> Dict[str, int]:
        """Messages stored in the database per topic (this process)."""
        return self.tally.snapshot()[3]

    def _drop(self, per_topic: Dict[str, int], why: str) -> None:
        self.tally.drop(per_topic, why)
        total = sum(per_topic.values())
        self._set_fault(f"dropped {total} messages ({why})")
        log.error("dropped %d messages %s: %s", total, per_topic, why)

    # -- the writers ---------------------------------------------------------------------------
    def start(self) -> "Recorder":
        if self.spool.pending:
            log.info("spool %s holds %d messages from an earlier run; draining them",
                     self.spool.path, self.spool.pending_records)
        self._threads = [threading.Thread(target=self._supervise, args=(index,),
                                          name=f"ros_mongo_writer_{index}", daemon=True)
                         for index in range(self.writers)]
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
        self.quarantine.close()
        return self.counts()

    def _supervise(self, index: int) -> None:
        """Run a writer; restart it after any unexpected failure (reported, never silent)."""
        while True:
            try:
                self._run(index)
                return
            except Exception as err:  # noqa: BLE001 - a writer must never die silently
                self._add("writer_restarts", 1)
                self._set_fault(f"writer {index} failed and was restarted: {type(err).__name__}: {err}")
                log.exception("writer %d failed; restarting it", index)
                if self._stopping and time.monotonic() > self._deadline:
                    return
                time.sleep(min(self.retry_period, 1.0))

    def _run(self, index: int) -> None:
        while True:
            items, ticket = self._take()
            if ticket is not None:
                self._write(items, ticket)
            if index == 0:  # one thread probes and drains
                self._collect_events()
                self._probe_and_drain()
            with self._cond:
                if self._stopping and not self._queue:
                    break
        if index == 0:
            for thread in self._threads[1:]:
                thread.join(max(0.0, self._deadline - time.monotonic()))
            while self.spool.pending and self.db_ok and time.monotonic() < self._deadline:
                self._drain_once()
            self._collect_events()
            self._release()

    def _take(self) -> Tuple[List[tuple], Optional[int]]:
        with self._cond:
            if not self._queue and not self._chunker.open and not self._stopping:
                self._idle += 1  # until a message arrives (receive notifies) or housekeeping is due
                self._cond.wait(IDLE_PERIOD if self.db_ok else min(IDLE_PERIOD, self.retry_period))
                self._idle -= 1
            deadline = time.monotonic() + self.batch_period
            while len(self._queue) < self.batch_size and not self._stopping:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            if self._chunker.open:  # chunks open long enough (all when stopping) join the queue
                self._queue.extend(self._chunker.flush() if self._stopping
                                   else self._chunker.due(time.monotonic()))
            items, size, count = [], 0, 0
            while self._queue and count < self.batch_size and size < 32 * 1024 * 1024:
                item = self._queue.popleft()
                items.append(item)
                count += item_messages(item)
                size += item_cost(item)
            self._queued_bytes -= size
            self._queued_messages -= count
            if not items:
                return items, None
            ticket = self._tickets
            self._tickets += 1
            return items, ticket

    def _write(self, items: List[tuple], ticket: int) -> None:
        """Decode (in parallel with other writers), then write in ticket order."""
        try:
            entries = [item_entry(item, self.records.record) for item in items]
        except Exception as err:  # noqa: BLE001 - a decoding bug must not lose the batch
            log.exception("cannot decode a batch; storing it without decoded fields")
            self._set_fault(f"decoding failed: {type(err).__name__}: {err}")
            entries = [item_entry(item, self.records.raw) for item in items]
        with self._order:
            while self._turn != ticket:
                self._order.wait()
        try:
            self._write_in_turn(entries, items)
        finally:
            with self._order:
                self._turn += 1
                self._order.notify_all()

    def _write_in_turn(self, entries: list, items: List[tuple]) -> None:
        unexpected = None
        if self.db_ok and not self.spool.pending:
            try:
                self._store(entries)
                self._clear_fault()
                return
            except StoreError as err:  # retry later / operator must act: keep everything
                self._went_down(err)
            except Exception as err:  # noqa: BLE001 - kept below, then the writer restarts
                self._went_down(StoreError(f"unexpected {type(err).__name__} while writing: {err}"))
                unexpected = err
        try:
            self._spool(entries)
        except SpoolError as err:
            self._keep_in_memory(items, err)
        if unexpected is not None:
            raise unexpected

    def _spool(self, entries: list) -> None:
        with self._spill_lock:
            self.spool.append(entries, self._topics)
        self._add("spooled", sum(message_count(e) for e in entries))

    def _keep_in_memory(self, items: List[tuple], err: SpoolError) -> None:
        """The spool is full: back to the front of the queue while memory lasts, else dropped."""
        size = sum(item_cost(item) for item in items)
        with self._cond:
            # stopping: kept (and retried) until the stop's deadline, as the server may be back
            if (self._queued_bytes + size <= self.max_queue_bytes
                    and (not self._stopping or time.monotonic() < self._deadline)):
                self._queue.extendleft(reversed(items))
                self._queued_bytes += size
                self._queued_messages += sum(item_messages(item) for item in items)
                kept = True
            else:
                kept = False
        if kept:
            self._set_fault(f"{self.fault or 'database failing'}; and the spool refuses writes: {err}")
            time.sleep(min(self.retry_period, 1.0))  # wait for the database or for disk space
        else:
            per_topic: Dict[str, int] = {}
            for item in items:
                if item_messages(item):
                    topic = item.key[0] if isinstance(item, PendingChunk) else item[0][0]
                    per_topic[topic] = per_topic.get(topic, 0) + item_messages(item)
            self._drop(per_topic, f"memory and spool both exhausted: {err}")

    def _add(self, counter: str, value: int) -> None:
        self.tally.add(counter, value)

    def _store(self, entries: list, live: bool = True) -> None:
        self.writer.write(entries, live=live, deadline=self._deadline)

    # -- faults ----------------------------------------------------------------------------------
    def _set_fault(self, text: str) -> None:
        self.fault = self.last_fault = text

    def _clear_fault(self) -> None:
        if self.fault:
            log.info("writes work again (the fault was: %s)", self.fault)
        self.fault, self._failures = "", 0

    def _went_down(self, err: StoreError) -> None:
        first = self.db_ok
        self.db_ok = False
        self._failures += 1
        self._next_probe = time.monotonic() + self.retry_period * min(10, 2 ** (self._failures - 1))
        self._set_fault(str(err))
        if first:
            log.error("cannot write to the database (%s); spooling to %s", err, self.spool.path)

    def _probe_and_drain(self) -> None:
        if not self.db_ok:
            if time.monotonic() < self._next_probe:
                return
            try:
                self.store.connect()
                self.store.ping()
            except StoreError as err:
                self._went_down(err)
                return
            self.db_ok = True
            log.info("database answers again; draining %d spooled messages", self.spool.pending_records)
        while self.spool.pending and self.db_ok and time.monotonic() < self._deadline:
            self._drain_once()
        self._release()

    def _collect_events(self) -> None:
        """Decided event windows into their parts, the rest recycled (whether central answers
        or not: the rings hold `before` seconds)."""
        if self.deferral is not None and self.deferral.rings:
            lost, why = self.deferral.collect()
            if lost:
                self._drop(lost, why)

    def _release(self) -> None:
        """Write deferred parts whose condition holds, a batch at a time while fewer than a batch
        of live messages wait (the kept spool first: it holds live topics)."""
        if self.deferral is None or self.spool.pending:
            return
        for part in self.deferral.releasable():
            while (part.spool.pending and self.db_ok and len(self._queue) < self.batch_size
                   and time.monotonic() < self._deadline):
                self._add("released", self._drain_once(part.spool, self._release_bytes(), live=False))
            if len(self._queue) >= self.batch_size:
                return

    def _release_bytes(self) -> int:
        """Bytes per released batch: small beside the cap, so live writes wait little behind it."""
        if self.bandwidth is None:
            return RELEASE_BYTES
        return int(min(RELEASE_BYTES, self.bandwidth.burst / 4))

    def _drain_once(self, spool: Optional[BoundedSpool] = None, max_bytes: int = 32 * 1024 * 1024,
                    live: bool = True) -> int:
        """Write the next entries of `spool` (default: the recorder's); the messages written."""
        spool = spool or self.spool
        entries, token = spool.read(max_entries=self.batch_size, max_bytes=max_bytes)
        records = sum(message_count(e) for e in entries)
        self.records.complete(entries)
        try:
            self._store(entries, live)
        except StoreError as err:  # never skipped: the entries stay in the spool
            spool.release()
            self._went_down(err)
            return 0
        self._clear_fault()
        spool.commit(token, records)
        if not spool.pending:
            log.info("spool %s drained", spool.path)
        return records

