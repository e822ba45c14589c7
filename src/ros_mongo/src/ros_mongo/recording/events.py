"""The rolling window of an `upload: on_event` rule (no ROS): the last `before` seconds of its
topics on the robot's disk, kept around triggers, recycled otherwise.

Messages go to ring segments, `<prefix>.ring.<n>` (the spool's framed format), a new segment every
`step` seconds and at every window boundary. A trigger at time t with reason r keeps
[t - before, t + after] (windows are kept in `<prefix>.windows`, so they outlive a restart). A
message is decided once it is older than `now - before` (no later trigger can reach it): inside
one or more windows it is kept, once, tagged `event:<reason>` for each of them; outside every
window it is recycled (counted per topic). So a window reaches the rule's part `before` seconds
after its end, with the reasons of every trigger that covers each message. `collect` returns
the kept messages of every segment whose messages are all decided; the caller stores them in the
rule's part of the spool and then calls `done`, which deletes the segment (killed in between: the
segment is collected again and the message ids keep each message once on central).
"""
import json
import os
import re
import threading
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Tuple

from ros_mongo.errors import SpoolError
from ros_mongo.recording.spool import Spool
from ros_mongo.records import MessageRecord, TopicInfo

__all__ = ["EventRing", "EVENT_TAG"]

EVENT_TAG = "event:"
_RING_RE = re.compile(r"\.ring\.(\d{8})$")


class _Segment:
    def __init__(self, number: int, spool: Spool, times: List[float]):
        self.number, self.spool, self.times = number, spool, times
        self.keys: set = set()  # topic keys whose info this segment holds


class EventRing:
    """One on_event rule's ring (see the module docstring).

    Args:
        prefix: path prefix of the ring's files.
        before, after: the default window around a trigger (seconds).
        step: seconds per ring segment (what is decided at once).
    """

    def __init__(self, prefix: str, *, before: float, after: float, step: float = 1.0):
        self.prefix, self.before, self.after, self.step = prefix, float(before), float(after), float(step)
        self.windows: List[Tuple[float, float, str]] = []
        self.segments: List[_Segment] = []
        self.recycled: Dict[str, int] = {}
        self._open: Optional[_Segment] = None
        self._lock = threading.RLock()

    # -- life cycle -------------------------------------------------------------------------------
    def open(self) -> "EventRing":
        folder, name = Path(self.prefix).parent, Path(self.prefix).name
        folder.mkdir(parents=True, exist_ok=True)
        numbers = sorted(int(m.group(1)) for p in folder.glob(name + ".ring.*")
                         if (m := _RING_RE.search(p.name)))
        for number in numbers:
            spool = self._spool(number).open()
            entries, _ = spool.read(max_entries=1 << 40, max_bytes=1 << 62)
            times = [e.receive_secs + e.receive_nsecs * 1e-9 for e in entries
                     if isinstance(e, MessageRecord)]
            self.segments.append(_Segment(number, spool, times))
        windows = Path(self.prefix + ".windows")
        if windows.exists():
            try:
                self.windows = [tuple(w) for w in json.loads(windows.read_text())]
            except (OSError, ValueError) as err:
                raise SpoolError(f"cannot read the event windows {windows}: {err}") from err
        return self

    def close(self) -> None:
        for segment in self.segments:
            segment.spool.close()

    def _spool(self, number: int) -> Spool:
        return Spool(f"{self.prefix}.ring.{number:08d}", max_bytes=1 << 62, min_free_bytes=0)

    # -- recording --------------------------------------------------------------------------------
    def append(self, record: MessageRecord, infos: Mapping[tuple, TopicInfo]) -> None:
        stamp = record.receive_secs + record.receive_nsecs * 1e-9
        key = (record.topic, record.msg_type, record.md5sum, record.callerid)
        with self._lock:
            segment = self._open
            if segment is None or stamp >= segment.times[0] + self.step or self._cut(segment, stamp):
                number = self.segments[-1].number + 1 if self.segments else 1
                segment = self._open = _Segment(number, self._spool(number).open(), [])
                self.segments.append(segment)
            entries = [record] if key in segment.keys or key not in infos else [infos[key], record]
            segment.spool.append(entries)
            segment.keys.add(key)
            segment.times.append(stamp)

    def _cut(self, segment: _Segment, stamp: float) -> bool:
        """Whether a window boundary lies between the segment's first message and `stamp`."""
        first = segment.times[0] if segment.times else stamp
        return any(first < edge <= stamp for start, end, _ in self.windows for edge in (start, end))

    def trigger(self, now: float, reason: str, before: Optional[float] = None,
                after: Optional[float] = None) -> Tuple[float, float]:
        """Keep [now - before, now + after] (defaults: the rule's; `before` at most the rule's)."""
        before = self.before if before is None else min(max(float(before), 0.0), self.before)
        after = self.after if after is None else max(float(after), 0.0)
        window = (now - before, now + after, str(reason))
        with self._lock:
            self.windows.append(window)
            self._open = None  # the next message starts a segment: windows cut segments
            self._save_windows()
        return window[0], window[1]

    # -- deciding ---------------------------------------------------------------------------------
    def collect(self, now: float) -> List[Tuple[int, List]]:
        """(segment number, kept entries) of every segment whose messages are all decided;
        recycled messages are counted. Call `done(number)` once the kept entries are stored."""
        ready = []
        with self._lock:
            if self._open is not None and self._open.times and now >= self._open.times[0] + self.step:
                self._open = None
            for segment in self.segments:
                if segment is self._open or not all(self._decided(t, now) for t in segment.times):
                    continue
                ready.append((segment.number, self._keep(segment)))
        return ready

    def _decided(self, stamp: float, now: float) -> bool:
        return stamp < now - self.before  # later triggers reach no further back

    def _reasons(self, stamp: float) -> List[str]:
        return [reason for start, end, reason in self.windows if start <= stamp <= end]

    def _keep(self, segment: _Segment) -> list:
        entries, _ = segment.spool.read(max_entries=1 << 40, max_bytes=1 << 62)
        kept: list = []
        for entry in entries:
            if not isinstance(entry, MessageRecord):
                kept.append(entry)  # topic infos: a later drain needs them
                continue
            reasons = self._reasons(entry.receive_secs + entry.receive_nsecs * 1e-9)
            if reasons:
                entry.tags = list(entry.tags) + sorted({EVENT_TAG + r for r in reasons})
                kept.append(entry)
            else:
                self.recycled[entry.topic] = self.recycled.get(entry.topic, 0) + 1
        return kept

    def done(self, number: int, now: float) -> None:
        """Delete a collected segment; forget windows no segment can reach any more."""
        with self._lock:
            for index, segment in enumerate(self.segments):
                if segment.number == number:
                    segment.spool.remove()
                    del self.segments[index]
                    break
            oldest = min([s.times[0] for s in self.segments if s.times] + [now - self.before])
            kept = [w for w in self.windows if w[1] >= oldest]
            if len(kept) != len(self.windows):
                self.windows = kept
                self._save_windows()

    def pending_records(self) -> int:
        with self._lock:
            return sum(len(s.times) for s in self.segments)

    def _save_windows(self) -> None:
        path = Path(self.prefix + ".windows")
        temporary = Path(str(path) + ".tmp")
        try:
            temporary.write_text(json.dumps(self.windows))
            os.replace(temporary, path)
        except OSError as err:
            raise SpoolError(f"cannot write the event windows {path}: {err}") from err
