"""Which messages go into chunks and when a chunk closes (the recorder's side of chunked topics;
no ROS), and the recorder's queue items: a topic info `(info,)`, a message `(key, raw, secs,
nsecs)` or a closed `PendingChunk`. The stored form of a chunk: ros_mongo.storage.chunks."""
import re
from typing import Dict, List, Sequence

from ros_mongo.storage.chunks import CHUNK_SPAN, ChunkRecord

__all__ = ["ChunkPolicy", "Chunker", "PendingChunk", "ITEM_OVERHEAD", "item_cost", "item_entry",
           "item_messages"]

#: Bytes a queued message costs beyond its payload (the bytes object, the queue entry, its tuple
#: and numbers, measured with sys.getsizeof on CPython 3.8-3.11).
ITEM_OVERHEAD = 200


class PendingChunk:
    """Received messages of one topic key waiting for their chunk to close (recorder queue item)."""

    __slots__ = ("key", "raws", "secs", "nsecs", "opened", "nbytes")

    def __init__(self, key: tuple, opened: float):
        self.key, self.opened = key, opened
        self.raws: List[bytes] = []
        self.secs: List[int] = []
        self.nsecs: List[int] = []
        self.nbytes = 0

    def add(self, raw: bytes, secs: int, nsecs: int) -> None:
        self.raws.append(raw)
        self.secs.append(secs)
        self.nsecs.append(nsecs)
        self.nbytes += len(raw)

    def first_time(self) -> float:
        return self.secs[0] + self.nsecs[0] * 1e-9

    def __len__(self) -> int:
        return len(self.raws)


class Chunker:
    """Groups the messages of chunked topics into closed `PendingChunk`s: a chunk closes when it
    holds `max_messages`, when a message comes `CHUNK_SPAN` s (receive time) after its first one or
    before its last one (that message opens the next), and when it has been open `period` s of
    wall time (`due`; at most `CHUNK_SPAN`). So a chunk's receive times never go back and span
    less than `CHUNK_SPAN`. Not thread-safe: the recorder calls it under its queue lock."""

    def __init__(self, max_messages: int = 1000, period: float = CHUNK_SPAN):
        if max_messages < 1:
            raise ValueError(f"chunk max_messages must be positive, got {max_messages!r}")
        _check_period(period)
        self.max_messages, self.period = int(max_messages), float(period)
        self.open: Dict[tuple, PendingChunk] = {}

    def add(self, key: tuple, raw: bytes, secs: int, nsecs: int, now: float) -> List[PendingChunk]:
        """Add one message; the chunks it closed (none, mostly)."""
        chunk = self.open.get(key)
        closed = []
        if chunk is not None and (secs + nsecs * 1e-9 - chunk.first_time() >= CHUNK_SPAN
                                  or (secs, nsecs) < (chunk.secs[-1], chunk.nsecs[-1])):
            closed.append(self.open.pop(key))
            chunk = None
        if chunk is None:
            chunk = self.open[key] = PendingChunk(key, now)
        chunk.add(raw, secs, nsecs)
        if len(chunk) >= self.max_messages:
            closed.append(self.open.pop(key))
        return closed

    def due(self, now: float) -> List[PendingChunk]:
        """Chunks open for `period` s or more, closed."""
        keys = [key for key, chunk in self.open.items() if now - chunk.opened >= self.period]
        return [self.open.pop(key) for key in keys]

    def flush(self) -> List[PendingChunk]:
        """Every open chunk, closed."""
        chunks, self.open = list(self.open.values()), {}
        return chunks


class ChunkPolicy:
    """Which topics are chunked: names fully matching one of `patterns` (regular expressions), and,
    when `min_rate` > 0, every topic once it received `min_rate` messages within one second of
    receive time (from then on). `max_messages`: a chunk's size limit; `period`: the wall time a
    chunk stays open at most (the Chunker's). Not thread-safe (the recorder calls it under its
    queue lock)."""

    def __init__(self, patterns: Sequence[str] = (), min_rate: float = 0.0, max_messages: int = 1000,
                 period: float = CHUNK_SPAN):
        if min_rate < 0 or max_messages < 1:
            raise ValueError(f"chunk rate must not be negative and max messages must be positive, got "
                             f"{min_rate!r} and {max_messages!r}")
        _check_period(period)
        self.patterns = [re.compile(p) for p in patterns]
        self.min_rate, self.max_messages, self.period = float(min_rate), int(max_messages), float(period)
        self._decided: Dict[str, bool] = {}
        self._windows: Dict[str, List[float]] = {}   # topic -> [window start, messages in it]

    @property
    def active(self) -> bool:
        return bool(self.patterns) or self.min_rate > 0

    def chunked(self, topic: str, stamp: float) -> bool:
        """Whether the message of `topic` received at `stamp` (s) goes into a chunk."""
        decided = self._decided.get(topic)
        if decided is None:
            decided = any(p.fullmatch(topic) for p in self.patterns)
            self._decided[topic] = decided
        if decided or self.min_rate <= 0:
            return decided
        window = self._windows.setdefault(topic, [stamp, 0])
        if not 0 <= stamp - window[0] < 1.0:
            window[0], window[1] = stamp, 0
        window[1] += 1
        if window[1] >= self.min_rate:
            self._decided[topic] = True
            return True
        return False


def _check_period(period: float) -> None:
    if not 0.0 < float(period) <= CHUNK_SPAN:
        raise ValueError(f"chunk period must be above 0 and at most {CHUNK_SPAN} s (what readers "
                         f"allow for a chunk), got {period!r}")


def item_messages(item) -> int:
    """Messages a queue item holds (a topic info: 0)."""
    if isinstance(item, PendingChunk):
        return len(item)
    return 0 if len(item) == 1 else 1


def item_cost(item) -> int:
    """Bytes a queue item counts for in the recorder's `max_queue_bytes`."""
    if isinstance(item, PendingChunk):
        return item.nbytes + ITEM_OVERHEAD * len(item)
    return 0 if len(item) == 1 else len(item[1]) + ITEM_OVERHEAD


def item_entry(item, build):
    """The entry of a queue item: its topic info, or `build(key, raw, secs, nsecs)`'s record of
    its message, or a ChunkRecord of its messages' records."""
    if isinstance(item, PendingChunk):
        return ChunkRecord([build(item.key, raw, secs, nsecs)
                            for raw, secs, nsecs in zip(item.raws, item.secs, item.nsecs)])
    return item[0] if len(item) == 1 else build(*item)
