"""The recorder's outage buffer on disk: bounded, with a stated policy per topic when full (no ROS).

A `BoundedSpool` holds two kinds of spool files (ros_mongo.recording.spool's framed format):
- the *kept* file (`<path>`): messages of every topic not named droppable, in order;
- *droppable* segments (`<path>.drop.<n>`): messages of the droppable topics (by default camera
  images: `sensor_msgs/Image`, `sensor_msgs/CompressedImage`), in segments of about
  `segment_bytes`, oldest first.

Together they stay under `max_bytes` (and leave `min_free_bytes` free on the file system). When an
append would cross either bound, the oldest droppable segment is deleted, its messages counted as
dropped per topic (`dropped`), and so on until the append fits; a droppable message that still
does not fit is dropped itself (counted). Only when no droppable data is left does an append of
kept messages raise SpoolFull (the recorder then holds the batch in memory, and counts per topic
what memory cannot hold either). So: odometry, scans and every other non-droppable topic are kept
whole until the disk itself is exhausted; the droppable topics lose their oldest messages first;
nothing is dropped without being counted.

Each file starts every topic's messages with that topic's info (a later recorder may drain the
spool, and a deleted segment takes its infos with it). Reads drain the kept file first, then the
droppable segments from the oldest (per topic the order is always kept). `read` returns a token
for `commit`; a segment being read is never deleted under the reader. Records keep their ids, so
a batch drained twice (killed between write and commit) is still stored once.
"""
import re
import threading
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Tuple, Union

from ros_mongo.errors import SpoolError
from ros_mongo.recording.limits import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES, DROPPABLE_TYPES
from ros_mongo.recording.spool import Spool, SpoolFull, frames
from ros_mongo.records import MessageRecord, TopicInfo

__all__ = ["BoundedSpool", "DropPolicy", "DROPPABLE_TYPES"]

_Key = Tuple[str, str, str, str]  # topic, type, md5sum, publisher
_SEGMENT_RE = re.compile(r"\.drop\.(\d{8})$")
_UNLIMITED = 1 << 62


class DropPolicy:
    """Which topics may lose their oldest messages when the spool is full: those of `types`, and
    those whose name matches one of the regular expressions `topics`."""

    def __init__(self, types: Sequence[str] = DROPPABLE_TYPES, topics: Sequence[str] = ()):
        self.types = frozenset(types)
        self.topics = [re.compile(pattern) for pattern in topics]
        self._cache: Dict[Tuple[str, str], bool] = {}

    def droppable(self, topic: str, msg_type: str) -> bool:
        key = (topic, msg_type)
        answer = self._cache.get(key)
        if answer is None:
            answer = msg_type in self.types or any(p.search(topic) for p in self.topics)
            self._cache[key] = answer
        return answer

    def describe(self) -> str:
        parts = sorted(self.types) + [p.pattern for p in self.topics]
        return ", ".join(parts) if parts else "nothing (every topic is kept)"


class BoundedSpool:
    """The kept file plus droppable segments, under one size bound (see the module docstring).

    Args:
        path: the kept file; segments are `<path>.drop.<n>` beside it.
        max_bytes: bound on all files together.
        min_free_bytes: free space every append must leave on the file system.
        policy: which topics are droppable.
        segment_bytes: size at which a new droppable segment is started (default max_bytes / 16,
            at least 256 KiB): what is dropped at once when the spool is full.
        fsync: fsync every append.
    """

    def __init__(self, path: Union[str, Path], *, max_bytes: int = DEFAULT_MAX_BYTES,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES, policy: Optional[DropPolicy] = None,
                 segment_bytes: Optional[int] = None, fsync: bool = False):
        if max_bytes < 1 or min_free_bytes < 0:
            raise ValueError(f"spool max_bytes must be positive and min_free_bytes not negative, got "
                             f"{max_bytes!r} and {min_free_bytes!r}")
        self.path = Path(path)
        self.max_bytes, self.min_free_bytes, self.fsync = int(max_bytes), int(min_free_bytes), fsync
        self.policy = policy or DropPolicy()
        self.segment_bytes = int(segment_bytes or max(256 << 10, self.max_bytes // 16))
        self.kept = Spool(self.path, fsync=fsync, max_bytes=_UNLIMITED, min_free_bytes=min_free_bytes)
        self.segments: List[Tuple[int, Spool]] = []
        self.dropped: Dict[str, int] = {}   # messages dropped per topic (this process)
        self._lock = threading.RLock()
        self._written: Dict[int, set] = {}  # file id (0: kept) -> topic keys whose info it holds
        self._reading: Optional[int] = None

    # -- life cycle -------------------------------------------------------------------------------
    def open(self) -> "BoundedSpool":
        self.kept.open()
        numbers = sorted(int(m.group(1)) for p in self.path.parent.glob(self.path.name + ".drop.*")
                         if (m := _SEGMENT_RE.search(p.name)))
        try:
            for number in numbers:
                self.segments.append((number, self._segment(number).open()))
        except SpoolError:
            self.close()
            raise
        self._written = {0: set()}
        return self

    def close(self) -> None:
        self.kept.close()
        for _, segment in self.segments:
            segment.close()

    def _segment(self, number: int) -> Spool:
        return Spool(f"{self.path}.drop.{number:08d}", fsync=self.fsync, max_bytes=_UNLIMITED,
                     min_free_bytes=self.min_free_bytes)

    # -- state ------------------------------------------------------------------------------------
    @property
    def pending(self) -> bool:
        return self.kept.pending or any(s.pending for _, s in self.segments)

    @property
    def pending_records(self) -> int:
        return self.kept.pending_records + sum(s.pending_records for _, s in self.segments)

    @property
    def size(self) -> int:
        """Bytes on disk in all files."""
        return self.kept.size + sum(s.size for _, s in self.segments)

    def pending_topics(self) -> Dict[str, int]:
        """Messages not yet drained per topic, in all files (read from the frames' headers)."""
        counts: Dict[str, int] = {}
        with self._lock:
            for spool in [self.kept] + [s for _, s in self.segments]:
                for topic, count in spool.pending_topics().items():
                    counts[topic] = counts.get(topic, 0) + count
        return counts

    def dropped_total(self) -> int:
        with self._lock:
            return sum(self.dropped.values())

    # -- writing ----------------------------------------------------------------------------------
    def append(self, entries: Sequence[Union[TopicInfo, MessageRecord]],
               infos: Mapping[_Key, TopicInfo]) -> None:
        """Append entries (TopicInfos among them are taken as known infos); `infos` gives the info
        of every message's topic key. Kept messages go in one append (all or nothing: SpoolFull
        when even deleting every droppable segment leaves no room); droppable ones one by one,
        dropping the oldest droppable messages (or, last, themselves) when full: counted."""
        infos = dict(infos)
        kept, droppable = [], []
        for entry in entries:
            if isinstance(entry, TopicInfo):
                infos.setdefault((entry.topic, entry.msg_type, entry.md5sum, entry.callerid), entry)
            elif self.policy.droppable(entry.topic, entry.msg_type):
                droppable.append(entry)
            else:
                kept.append(entry)
        with self._lock:
            if kept:
                self._append_kept(kept, infos)
            for record in droppable:
                self._append_droppable(record, infos)

    def _with_infos(self, file_id: int, records: List[MessageRecord],
                    infos: Mapping[_Key, TopicInfo]) -> Tuple[list, set]:
        written = self._written.setdefault(file_id, set())
        entries: list = []
        new = set()
        for record in records:
            key = (record.topic, record.msg_type, record.md5sum, record.callerid)
            if key not in written and key not in new and key in infos:
                entries.append(infos[key])
                new.add(key)
            entries.append(record)
        return entries, new

    def _append_kept(self, records: List[MessageRecord], infos: Mapping[_Key, TopicInfo]) -> None:
        if not self.kept.pending:
            self._written[0] = set()  # an emptied file holds no infos any more
        entries, new = self._with_infos(0, records, infos)
        data, count = frames(entries)
        while True:
            if self.size + len(data) <= self.max_bytes:
                try:
                    self.kept.append_frames(data, count)
                    self._written[0] |= new
                    return
                except SpoolFull:  # short of free disk space
                    pass
            if not self._drop_oldest_segment():
                raise SpoolFull(f"spool {self.path} is full ({self.size} of {self.max_bytes} bytes, "
                                f"or short of {self.min_free_bytes} bytes free) and holds no droppable "
                                f"messages ({self.policy.describe()}) to make room")

    def _append_droppable(self, record: MessageRecord, infos: Mapping[_Key, TopicInfo]) -> None:
        while True:
            number, segment = self._writable_segment()
            entries, new = self._with_infos(number, [record], infos)
            data, count = frames(entries)
            if self.size + len(data) <= self.max_bytes:
                try:
                    segment.append_frames(data, count)
                    self._written[number] |= new
                    return
                except SpoolFull:  # short of free disk space
                    pass
            if not self._drop_oldest_segment():  # nothing older left: this message is dropped
                self._count_dropped({record.topic: 1})
                return

    def _writable_segment(self) -> Tuple[int, Spool]:
        if self.segments:
            number, segment = self.segments[-1]
            if segment.size < self.segment_bytes and number != self._reading:
                return number, segment
        number = self.segments[-1][0] + 1 if self.segments else 1
        segment = self._segment(number).open()
        self.segments.append((number, segment))
        self._written[number] = set()
        return number, segment

    def _drop_oldest_segment(self) -> bool:
        """Delete the oldest non-empty droppable segment that is not being read, counting its
        messages as dropped; False when there is none."""
        for index, (number, segment) in enumerate(self.segments):
            if number == self._reading or segment.size == 0:
                continue
            counts = segment.pending_topics()
            segment.remove()
            del self.segments[index]
            self._written.pop(number, None)
            self._count_dropped(counts)
            return True
        return False

    def _count_dropped(self, counts: Mapping[str, int]) -> None:
        for topic, count in counts.items():
            self.dropped[topic] = self.dropped.get(topic, 0) + count

    # -- draining ---------------------------------------------------------------------------------
    def read(self, max_entries: int = 500, max_bytes: int = 16 * 1024 * 1024) -> Tuple[list, tuple]:
        """The next entries to drain (the kept file first, then the oldest segment) and the token
        for `commit`."""
        with self._lock:
            if self.kept.pending:
                entries, offset = self.kept.read(max_entries, max_bytes)
                return entries, (0, offset)
            for number, segment in self.segments:
                if segment.pending:
                    self._reading = number
                    entries, offset = segment.read(max_entries, max_bytes)
                    return entries, (number, offset)
            return [], (0, 0)

    def commit(self, token: tuple, records: int) -> None:
        """Mark what `read` returned with `token` (holding `records` messages) as stored."""
        number, offset = token
        with self._lock:
            self._reading = None
            if number == 0:
                if offset:
                    self.kept.commit(offset, records)
                return
            for index, (segment_number, segment) in enumerate(self.segments):
                if segment_number == number:
                    segment.commit(offset, records)
                    if not segment.pending and index < len(self.segments) - 1:
                        segment.remove()  # drained, and not the one being written: delete it
                        del self.segments[index]
                        self._written.pop(number, None)
                    elif not segment.pending:
                        self._written[number] = set()
                    return

    def release(self) -> None:
        """Forget an unfinished read (its entries stay pending)."""
        with self._lock:
            self._reading = None

