"""What one recorder run counted (no ROS): its counters, the messages it dropped per topic with
the latest reason, and the messages central acknowledged per topic (the ledger's own counts)."""
import threading
from typing import Dict, Iterable, Tuple

from ros_mongo.storage.chunks import ChunkRecord, message_count

__all__ = ["Tally", "COUNTERS"]

COUNTERS = ("received", "stored", "dropped", "rejected", "quarantined", "spooled", "writer_restarts",
            "deferred", "released")


class Tally:
    """Thread-safe counts of one recorder run. `counts["received"]` alone is written without
    `lock`: by the recorder, under its queue lock (the per-message path)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.counts: Dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self.dropped: Dict[str, int] = {}
        self.reasons: Dict[str, str] = {}    # the latest reason per topic
        self.uploaded: Dict[str, int] = {}   # messages central acknowledged, per topic

    def add(self, counter: str, value: int) -> None:
        with self.lock:
            self.counts[counter] += value

    def drop(self, per_topic: Dict[str, int], why: str) -> None:
        """Count messages lost, per topic, and why."""
        with self.lock:
            for topic, count in per_topic.items():
                self.counts["dropped"] += count
                self.dropped[topic] = self.dropped.get(topic, 0) + count
                self.reasons[topic] = why

    def stored(self, records: Iterable) -> None:
        """Count records (messages or chunks) the store acknowledged."""
        with self.lock:
            for record in records:
                count = message_count(record)
                topic = record.records[0].topic if isinstance(record, ChunkRecord) else record.topic
                self.counts["stored"] += count
                self.uploaded[topic] = self.uploaded.get(topic, 0) + count

    def snapshot(self) -> Tuple[Dict[str, int], Dict[str, int], Dict[str, str], Dict[str, int]]:
        """Copies of (counts, dropped per topic, latest reason per topic, uploaded per topic)."""
        with self.lock:
            return dict(self.counts), dict(self.dropped), dict(self.reasons), dict(self.uploaded)
