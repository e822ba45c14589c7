"""The replay core (no ROS): a query's stored messages handed to a publish callback with their
recorded timing (scaled by `rate`) or at a fixed rate, from a start offset, for a duration, looped.

The messages are read by a separate loader process (its own database connection; a few threads
fetch bytes kept in attachments / GridFS), so that parsing database answers never holds up the
player; the player's process only receives ready (topic, type, stamp, bytes) tuples through a pipe,
reads ahead (`prefetch` messages or `prefetch_mb`) and fills that before its clock starts (for at most
`preroll_timeout` s), since loading while playing competes for the processor on a small machine.
The player sleeps until each message is due and spins through the last fraction of a millisecond;
large messages (images, clouds) are handed early to a thread of their topic's own that publishes them
at their due time, so writing them does not delay the other topics.
"""
import gc
import logging
import pickle
import queue
import subprocess
import sys
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Deque, Dict, List, Optional

import genpy

from ros_mongo.errors import StoreError
from ros_mongo.query import Query
from ros_mongo.storage.store import MessageStore, open_store

__all__ = ["Replayer", "ReplayItem", "load"]

log = logging.getLogger(__name__)
_SPIN = 0.0003  # seconds before a due time when sleeping gives way to spinning
_FETCHERS = 4  # loader threads fetching message bytes kept apart from the documents
_CHUNK_MESSAGES, _CHUNK_BYTES = 100, 4 * 1024 * 1024
_END = "end"


class ReplayItem:
    """One message to replay: topic, msg_type, md5sum, receive_stamp (genpy.Time), raw bytes."""

    __slots__ = ("topic", "msg_type", "md5sum", "receive_stamp", "raw")

    def __init__(self, topic: str, msg_type: str, md5sum: str, secs: int, nsecs: int, raw: bytes):
        self.topic, self.msg_type, self.md5sum, self.raw = topic, msg_type, md5sum, raw
        self.receive_stamp = genpy.Time(secs, nsecs)

    @property
    def receive_time(self) -> float:
        return self.receive_stamp.to_sec()


class Replayer:
    """Plays stored messages to `publish(ReplayItem)`; optional `clock(genpy.Time)` for /clock.

    Args:
        rate: speed factor for recorded timing (2.0 = twice as fast).
        start_offset: seconds after the first matching message to start at.
        duration: seconds of recorded time to play (0: all).
        loop: start over after the last message.
        fixed_rate: messages per second regardless of recorded timing (0: recorded timing).
        clock_period: seconds of wall time between clock callbacks while waiting.
        prefetch, prefetch_mb: messages / megabytes read ahead (at most).
        preroll_timeout: longest wait for the read-ahead to fill before playing.
        lane_min_bytes: messages at least this large are published by a thread of their topic's
            own at their due time (writing them then never delays other topics).
    """

    def __init__(self, store: MessageStore, publish: Callable[[ReplayItem], None], *,
                 clock: Optional[Callable[[genpy.Time], None]] = None, rate: float = 1.0,
                 start_offset: float = 0.0, duration: float = 0.0, loop: bool = False,
                 fixed_rate: float = 0.0, clock_period: float = 0.01, prefetch: int = 100000,
                 prefetch_mb: float = 1024.0, preroll_timeout: float = 60.0, lane_min_bytes: int = 65536):
        for name, value in (("rate", rate), ("clock_period", clock_period)):
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value!r}")
        for name, value in (("start_offset", start_offset), ("duration", duration),
                            ("fixed_rate", fixed_rate)):
            if not value >= 0:
                raise ValueError(f"{name} must not be negative, got {value!r}")
        self.store, self.publish, self.clock = store, publish, clock
        self.rate, self.start_offset, self.duration = float(rate), float(start_offset), float(duration)
        self.loop, self.fixed_rate, self.clock_period = bool(loop), float(fixed_rate), float(clock_period)
        self.prefetch, self.prefetch_bytes = max(2, int(prefetch)), max(1, int(prefetch_mb * 2 ** 20))
        self.preroll_timeout = float(preroll_timeout)
        self.lane_bytes = int(lane_min_bytes)
        self.published = 0
        self._count_lock = threading.Lock()
        self._late: List[float] = []
        self.state, self.error = "idle", ""
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    @property
    def playing(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, query: Query) -> None:
        """Start playing `query` (stops a running replay first)."""
        self.stop()
        self._stop.clear()
        self.published, self.state, self.error = 0, "playing", ""
        self._thread = threading.Thread(target=self._run, args=(query,), name="ros_mongo_replay", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> bool:
        """Stop playing; True if something was playing."""
        was_playing = self.playing
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if was_playing:
            self.state = "stopped"
        return was_playing

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Wait for the replay to end; True if it has."""
        if self._thread is not None:
            self._thread.join(timeout)
        return not self.playing

    def _run(self, query: Query) -> None:
        try:
            window = self._window(query)
            while window is not None and not self._stop.is_set():
                self._play(window)
                if not self.loop:
                    break
            if not self._stop.is_set():
                self.state = "finished"
        except StoreError as err:
            self.state, self.error = "failed", str(err)
            log.error("replay failed: %s", err)

    def _window(self, query: Query) -> Optional[Query]:
        first = next(iter(self.store.find(query, limit=1, decoded=False)), None)
        if first is None:
            log.info("replay: no messages match %s", query.describe())
            return None
        begin = first.receive_time + self.start_offset
        return query.with_times(begin, begin + self.duration if self.duration else None)

    def _play(self, window: Query) -> None:
        buffer = _Buffer(self.prefetch, self.prefetch_bytes, self._stop)
        loader = _LoaderProcess(self.store, window, buffer)
        began = time.monotonic()
        buffer.wait_filled(loader.receiver, timeout=self.preroll_timeout)  # preroll
        prerolled, self._late = time.monotonic() - began, []
        lanes: Dict[str, _Lane] = {}
        wall_start = begin = None
        index = 0
        gc.collect()
        gc.freeze()  # what exists now is never scanned again: collections while playing stay short
        try:
            while not self._stop.is_set():
                item = buffer.get()
                if item is _END:
                    break
                if isinstance(item, StoreError):
                    raise item
                if wall_start is None:
                    wall_start, begin = time.monotonic(), item.receive_time
                if self.fixed_rate:
                    due = wall_start + index / self.fixed_rate
                else:
                    due = wall_start + (item.receive_time - begin) / self.rate
                index += 1
                if len(item.raw) >= self.lane_bytes:  # written by its topic's thread, at `due`
                    if item.topic not in lanes:
                        lanes[item.topic] = _Lane(self)
                    lanes[item.topic].items.put((due, item))
                    continue
                if not _sleep_until(due, self._stop, self._ticker(wall_start, begin), self.clock_period):
                    break
                self._emit(item, due)
        finally:
            gc.unfreeze()
            for lane in lanes.values():
                lane.close()
            loader.close()
        _log_lateness(self._late, prerolled)

    def _emit(self, item: ReplayItem, due: float) -> None:
        if self.clock is not None:
            self.clock(item.receive_stamp)
        self._late.append(time.monotonic() - due)
        self.publish(item)
        with self._count_lock:
            self.published += 1

    def _ticker(self, wall_start: float, begin: float) -> Optional[Callable[[], None]]:
        """The clock published while waiting (recorded time running at `rate`)."""
        if self.clock is None:
            return None
        return lambda: self.clock(genpy.Time.from_sec(begin + (time.monotonic() - wall_start) * self.rate))


def _sleep_until(due: float, stop: threading.Event, tick: Optional[Callable[[], None]] = None,
                 tick_period: float = 0.01) -> bool:
    """Sleep until `due`, spinning through its last fraction of a millisecond and calling `tick`
    every `tick_period` meanwhile; False if `stop` was set. The spin gives the interpreter lock
    away on every turn, so a thread spinning towards its message never holds up another thread's
    message that is due first (holding it, a spinner keeps it for up to the switch interval)."""
    while True:
        remaining = due - time.monotonic()
        if remaining <= 0:
            return True
        if stop.is_set():
            return False
        if remaining > _SPIN:
            step = remaining - _SPIN
            if tick is not None:
                step = min(step, tick_period)
                tick()
            time.sleep(min(step, 0.1))
        else:
            time.sleep(0)  # spinning: the interpreter lock goes to a thread due first, at once


class _Lane:
    """A thread that publishes one topic's large messages at their due times, so that writing a
    large message never holds up the messages of other topics."""

    def __init__(self, replayer: "Replayer"):
        self.replayer = replayer
        self.items: queue.Queue = queue.Queue()
        self.thread = threading.Thread(target=self._run, name="ros_mongo_lane", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while True:
            entry = self.items.get()
            if entry is None:
                return
            due, item = entry
            if _sleep_until(due, self.replayer._stop):
                self.replayer._emit(item, due)

    def close(self) -> None:
        """Let the lane publish what it holds (unless stopped), then end it."""
        self.items.put(None)
        self.thread.join()


def _log_lateness(late: List[float], prerolled: float) -> None:
    if late:
        late.sort()
        log.info("replayed %d messages after a %.2f s preroll; published late by p50 %.3f ms, "
                 "p99 %.3f ms, max %.3f ms", len(late), prerolled, late[len(late) // 2] * 1e3,
                 late[int(len(late) * 0.99)] * 1e3, late[-1] * 1e3)


class _LoaderProcess:
    """`python -m ros_mongo.replay.loader` reading `window`; a receiver thread moves its chunks of message
    tuples into the player's buffer."""

    def __init__(self, store: MessageStore, window: Query, buffer: "_Buffer"):
        url, options = store.reopen_args()
        self.process = subprocess.Popen([sys.executable, "-m", "ros_mongo.replay.loader"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        pickle.dump((url, options, window), self.process.stdin)  # credentials go through the pipe only
        self.process.stdin.close()
        self.buffer = buffer
        self.receiver = threading.Thread(target=self._receive, name="ros_mongo_receiver", daemon=True)
        self.receiver.start()

    def _receive(self) -> None:
        while True:
            try:
                kind, payload = pickle.load(self.process.stdout)
            except (EOFError, pickle.UnpicklingError, OSError):
                if not self.buffer.stop_loading.is_set():
                    status = self.process.wait()
                    self.buffer.put(StoreError(f"the loader process ended with status {status}"))
                return
            if kind == "data":
                for fields in payload:
                    if not self.buffer.put(ReplayItem(*fields), len(fields[-1])):
                        return
            else:
                self.buffer.put(_END if kind == _END else StoreError(payload))
                return

    def close(self) -> None:
        self.buffer.stop_loading.set()
        if self.process.poll() is None:
            self.process.terminate()
        self.process.wait()
        self.receiver.join(5)
        self.process.stdout.close()


def load(url: str, options: dict, window: Query, out) -> None:
    """The loader process's work: pickled (kind, payload) chunks to the binary stream `out`."""
    def send(item) -> None:
        pickle.dump(item, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()
    try:
        store = open_store(url, connect=False, **options)
        chunk, size = [], 0
        pending: Deque = deque()
        with ThreadPoolExecutor(max_workers=_FETCHERS) as pool:
            for message in store.find(window, decoded=False):
                pending.append(pool.submit(_fields, message))
                while len(pending) > _FETCHERS * 2 or (pending and pending[0].done()):
                    fields = pending.popleft().result()
                    chunk.append(fields)
                    size += len(fields[-1])
                    if len(chunk) >= _CHUNK_MESSAGES or size >= _CHUNK_BYTES:
                        send(("data", chunk))
                        chunk, size = [], 0
            chunk += [future.result() for future in pending]
        send(("data", chunk))
        send((_END, None))
    except StoreError as err:
        send(("error", str(err)))
    except BrokenPipeError:
        pass  # the player stopped


def _fields(message) -> tuple:
    stamp = message.receive_stamp
    return message.topic, message.msg_type, message.md5sum, stamp.secs, stamp.nsecs, message.raw


class _Buffer:
    """A FIFO bounded by message count and bytes that gives way once the replay is stopped."""

    def __init__(self, max_items: int, max_bytes: int, stop: threading.Event):
        self.max_items, self.max_bytes, self.stop = max_items, max_bytes, stop
        self.stop_loading = threading.Event()
        self.items: Deque = deque()
        self.bytes = 0
        self.cond = threading.Condition()

    def _halted(self) -> bool:
        return self.stop.is_set() or self.stop_loading.is_set()

    def put(self, item, size: int = 0) -> bool:
        """Append (waiting for room); False if the replay was stopped meanwhile."""
        with self.cond:
            while self.items and (len(self.items) >= self.max_items or self.bytes + size > self.max_bytes):
                if self._halted():
                    return False
                self.cond.wait(0.1)
            self.items.append((item, size))
            self.bytes += size
            if len(self.items) == 1:
                self.cond.notify_all()
            return not self._halted()

    def get(self):
        """The next item (_END once the replay is stopped)."""
        with self.cond:
            while not self.items:
                if self.stop.is_set():
                    return _END
                self.cond.wait(0.1)
            item, size = self.items.popleft()
            self.bytes -= size
            if len(self.items) < self.max_items // 2 and self.bytes < self.max_bytes // 2:
                self.cond.notify_all()  # wake the receiver only once there is room for a batch
            return item

    def wait_filled(self, receiver: threading.Thread, timeout: float) -> None:
        """Until full, the loading finished, the replay stopped or `timeout` passed."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while receiver.is_alive() and not self.stop.is_set() and time.monotonic() < deadline \
                    and len(self.items) < self.max_items - 1 and self.bytes < self.max_bytes - _CHUNK_BYTES:
                self.cond.wait(0.05)
