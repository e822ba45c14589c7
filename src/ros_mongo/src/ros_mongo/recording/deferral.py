"""The deferred parts of the spool (no ROS): one bounded spool per `upload: when` rule, holding
that rule's topics on the robot's disk until its condition holds.

A part is a `BoundedSpool` at `<spool_path>.when.<rule name>` with the recorder's drop policy and
its own bound (the rule's `max_mb`): when it is full its oldest droppable messages (camera images by
default) go first, counted per topic; kept topics that no longer fit are counted as dropped by the
recorder. Parts outlive the recorder: the next one opens them and releases them when the condition
holds. Records keep their ids, so a part drained twice (killed between write and commit) is still
stored once.
"""
import datetime
import threading
from typing import Callable, Dict, List, Optional

from ros_mongo.recording.bounded_spool import BoundedSpool, DropPolicy
from ros_mongo.recording.upload_rules import UploadRule, UploadRules

__all__ = ["DeferredPart", "Deferral"]


class DeferredPart:
    """One `when` rule's spool and the lock its appends take."""

    def __init__(self, rule: UploadRule, spool: BoundedSpool):
        self.rule, self.spool = rule, spool
        self.lock = threading.Lock()


class Deferral:
    """The deferred parts of `rules`, the dock states their conditions read, and which parts may
    be released now.

    Args:
        rules: the upload rules.
        spool_path: the recorder's spool path; parts are `<spool_path>.when.<rule name>`.
        policy, min_free_bytes, fsync: as the recorder's spool.
        clock: the local time of day now (for daily windows; replaceable in tests).
    """

    def __init__(self, rules: UploadRules, spool_path: str, *, policy: Optional[DropPolicy] = None,
                 min_free_bytes: int = 0, fsync: bool = False,
                 clock: Callable[[], datetime.time] = lambda: datetime.datetime.now().time()):
        self.rules, self.clock = rules, clock
        self.parts: Dict[str, DeferredPart] = {
            rule.name: DeferredPart(rule, BoundedSpool(f"{spool_path}.when.{rule.name}",
                                                       max_bytes=int(rule.max_mb * 2 ** 20),
                                                       min_free_bytes=min_free_bytes, policy=policy,
                                                       fsync=fsync))
            for rule in rules.deferred}
        self.docked: Dict[str, bool] = {}

    def open(self) -> "Deferral":
        for part in self.parts.values():
            part.spool.open()
        return self

    def close(self) -> None:
        for part in self.parts.values():
            part.spool.close()

    def part_for(self, topic: str) -> Optional[DeferredPart]:
        """The part holding `topic`'s messages, or None for a topic that is not deferred."""
        rule = self.rules.rule_for(topic)
        return self.parts.get(rule.name) if rule.mode == "when" else None

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
