"""The deferred parts of the spool (no ROS): one bounded spool per `upload: when` rule, holding
that rule's topics on the robot's disk until its condition holds, and per `upload: on_event` rule
a ring (ros_mongo.recording.events) whose kept windows go to the rule's part
(`<spool_path>.event.<rule name>`), released at once or by the rule's condition.

A part is a `BoundedSpool` at `<spool_path>.when.<rule name>` with the recorder's drop policy and
its own bound (the rule's `max_mb`): when it is full its oldest droppable messages (camera images by
default) go first, counted per topic; kept topics that no longer fit are counted as dropped by the
recorder. Parts outlive the recorder: the next one opens them and releases them when the condition
holds. Records keep their ids, so a part drained twice (killed between write and commit) is still
stored once.
"""
import datetime
import threading
import time
from typing import Callable, Dict, List, Mapping, Optional, Tuple, Union

from ros_mongo.errors import SpoolError
from ros_mongo.recording.bounded_spool import BoundedSpool, DropPolicy
from ros_mongo.recording.events import EventRing
from ros_mongo.recording.upload_rules import UploadRule, UploadRules
from ros_mongo.records import MessageRecord, TopicInfo

__all__ = ["DeferredPart", "Deferral"]

_KIND = {"when": "when", "on_event": "event"}


class DeferredPart:
    """One `when` rule's spool and the lock its appends take."""

    def __init__(self, rule: UploadRule, spool: BoundedSpool):
        self.rule, self.spool = rule, spool
        self.lock = threading.Lock()

    def append(self, record: MessageRecord, infos: Mapping[tuple, TopicInfo]) -> None:
        with self.lock:
            self.spool.append([record], infos)


class Deferral:
    """The deferred parts of `rules`, the dock states their conditions read, and which parts may
    be released now.

    Args:
        rules: the upload rules.
        spool_path: the recorder's spool path; parts are `<spool_path>.when.<rule name>`.
        policy, min_free_bytes, fsync: as the recorder's spool.
        clock: the local time of day now (for daily windows; replaceable in tests).
        now: the time in seconds that receive times are in (for event windows).
    """

    def __init__(self, rules: UploadRules, spool_path: str, *, policy: Optional[DropPolicy] = None,
                 min_free_bytes: int = 0, fsync: bool = False,
                 clock: Callable[[], datetime.time] = lambda: datetime.datetime.now().time(),
                 now: Callable[[], float] = time.time):
        self.rules, self.clock, self.now = rules, clock, now
        self.parts: Dict[str, DeferredPart] = {
            rule.name: DeferredPart(rule, BoundedSpool(f"{spool_path}.{_KIND[rule.mode]}.{rule.name}",
                                                       max_bytes=int(rule.max_mb * 2 ** 20),
                                                       min_free_bytes=min_free_bytes, policy=policy,
                                                       fsync=fsync))
            for rule in rules.deferred}
        self.rings: Dict[str, EventRing] = {
            rule.name: EventRing(f"{spool_path}.event.{rule.name}", before=rule.before, after=rule.after)
            for rule in rules.events}
        self.docked: Dict[str, bool] = {}

    def open(self) -> "Deferral":
        for part in self.parts.values():
            part.spool.open()
        for ring in self.rings.values():
            ring.open()
        return self

    def close(self) -> None:
        for part in self.parts.values():
            part.spool.close()
        for ring in self.rings.values():
            ring.close()

    def target_for(self, topic: str) -> Optional[Union[DeferredPart, EventRing]]:
        """Where `topic`'s messages go on the robot (its part or its ring), None for live ones."""
        rule = self.rules.rule_for(topic)
        if rule.mode == "on_event":
            return self.rings[rule.name]
        return self.parts.get(rule.name) if rule.mode == "when" else None

    def trigger(self, reason: str, before: Optional[float] = None,
                after: Optional[float] = None) -> List[Tuple[str, float, float]]:
        """Keep a window around now in every ring: (rule, start, end) of each. `before` / `after`
        None or 0: each rule's own; `before` is at most the rule's (its ring holds no more).
        ValueError for a negative or non-finite value, or when no rule is on_event."""
        for name, value in (("before", before), ("after", after)):
            if value is not None and not 0.0 <= float(value) < float("inf"):
                raise ValueError(f"event {name} must be a finite number of seconds >= 0, got {value!r}")
        if not self.rings:
            raise ValueError("no upload: on_event rule: there is no window to keep")
        before, after = before or None, after or None
        now = self.now()
        return [(name, *ring.trigger(now, reason, before, after)) for name, ring in self.rings.items()]

    def collect(self) -> Tuple[Dict[str, int], str]:
        """Move the decided windows of the rings into their parts; the messages the parts could not
        take, per topic, and why."""
        lost: Dict[str, int] = {}
        why = ""
        now = self.now()
        for name, ring in self.rings.items():
            part = self.parts[name]
            for number, entries in ring.collect(now):
                try:
                    with part.lock:
                        part.spool.append(entries, {})
                except SpoolError as err:
                    why = f"its part {name!r} of the spool is full: {err}"
                    for entry in entries:
                        if isinstance(entry, MessageRecord):
                            lost[entry.topic] = lost.get(entry.topic, 0) + 1
                ring.done(number, now)
        return lost, why

    def recycled(self) -> Dict[str, int]:
        """Messages of the rings that no trigger kept, per topic (this process)."""
        counts: Dict[str, int] = {}
        for ring in self.rings.values():
            for topic, count in dict(ring.recycled).items():
                counts[topic] = counts.get(topic, 0) + count
        return counts

    def set_docked(self, topic: str, docked: bool) -> None:
        self.docked[topic] = bool(docked)

    def holds(self, part: DeferredPart) -> bool:
        """Whether `part`'s condition holds now."""
        return part.rule.condition.holds(self.docked, self.clock())

    def releasable(self) -> List[DeferredPart]:
        """Parts holding messages whose condition holds now, in the rules' order."""
        return [p for p in self.parts.values() if p.spool.pending and self.holds(p)]

    def pending_records(self) -> int:
        return sum(p.spool.pending_records for p in self.parts.values())

    def pending_by_topic(self) -> Dict[str, int]:
        """Messages waiting on the robot per topic (read from the parts' frame headers)."""
        waiting: Dict[str, int] = {}
        for part in self.parts.values():
            for topic, count in part.spool.pending_topics().items():
                waiting[topic] = waiting.get(topic, 0) + count
        return waiting

    def dropped(self) -> Dict[str, int]:
        """Messages the parts' drop policy dropped, per topic (this process)."""
        dropped: Dict[str, int] = {}
        for part in self.parts.values():
            for topic, count in dict(part.spool.dropped).items():
                dropped[topic] = dropped.get(topic, 0) + count
        return dropped
