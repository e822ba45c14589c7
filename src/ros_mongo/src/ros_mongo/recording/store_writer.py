"""The recorder's writes to its store (no ROS): each topic's definition before its messages, the
upload cap on the encoded documents, documents refused on their own merits kept in the quarantine
file, and what the store acknowledged counted per topic."""
import logging
from typing import Callable, Dict, List, Mapping, Optional

from ros_mongo.errors import DocumentsRejected, SpoolError
from ros_mongo.recording.bandwidth import Bandwidth
from ros_mongo.recording.quarantine import Quarantine
from ros_mongo.recording.tally import Tally
from ros_mongo.records import MessageRecord, TopicInfo
from ros_mongo.storage.chunks import ChunkRecord, message_count
from ros_mongo.storage.store import MessageStore

__all__ = ["StoreWriter"]

log = logging.getLogger(__name__)


class StoreWriter:
    """Writes entries (topic infos, message records, chunks) of one recorder.

    Args:
        store: the recorder's store.
        topics: the recorder's topic infos by topic key (read, never changed here).
        tally: where stored, rejected and quarantined messages are counted.
        quarantine: where refused documents go.
        bandwidth: the upload cap (None: none).
        drop: how lost messages are reported ({topic: count}, why): the recorder's.
    """

    def __init__(self, store: MessageStore, topics: Mapping[tuple, TopicInfo], tally: Tally,
                 quarantine: Quarantine, bandwidth: Optional[Bandwidth],
                 drop: Callable[[Dict[str, int], str], None]):
        self.store, self.topics, self.tally = store, topics, tally
        self.quarantine, self.bandwidth, self.drop = quarantine, bandwidth, drop

    def write(self, entries: list, *, live: bool = True, deadline: float = float("inf")) -> None:
        """Store entries; documents refused on their own merits go to the quarantine file. Any
        other StoreError propagates (nothing was lost: ids dedupe the retry)."""
        records = [e for e in entries if isinstance(e, (MessageRecord, ChunkRecord))]
        for entry in entries:
            if isinstance(entry, TopicInfo):
                self.store.put_topic(entry)
        for key in {(r.topic, r.msg_type, r.md5sum, r.callerid) for r in records}:
            if key in self.topics:  # each topic's definition before its messages
                self.store.put_topic(self.topics[key])
        try:
            # no lookup before writing (the counts below are ours): each is stored once anyway
            if self.bandwidth is None:
                self.store.insert_records(records, look_up=False)
            else:  # the cap takes the bytes of the encoded documents
                prepared = self.store.prepare_records(records)
                self.bandwidth.take(sum(weight for _, _, weight in prepared.items), live=live,
                                    deadline=deadline)
                self.store.insert_prepared(prepared, look_up=False)
        except DocumentsRejected as err:
            refused = [r for r in records if r.id in err.rejected_ids]
            if len(refused) != err.rejected:  # the server did not name them all: one at a time
                refused = [r for r in records if not self._insert_alone(r)]
            self._quarantine(refused, err)
            skip = {id(r) for r in refused}
            self.tally.stored(r for r in records if id(r) not in skip)
            return
        # counted once: a failed attempt that reached the database anyway was not counted
        self.tally.stored(records)

    def _insert_alone(self, record: MessageRecord) -> bool:
        try:
            self.store.insert_records([record], look_up=False)
            return True
        except DocumentsRejected:
            return False

    def _quarantine(self, refused: List[MessageRecord], err: DocumentsRejected) -> None:
        count = sum(map(message_count, refused))
        self.tally.add("rejected", count)
        try:
            self.quarantine.add(refused, self.topics)
        except SpoolError as error:
            per_topic: Dict[str, int] = {}
            for record in refused:
                per_topic[record.topic] = per_topic.get(record.topic, 0) + message_count(record)
            self.drop(per_topic, f"refused by the database and the quarantine file cannot be "
                                 f"written: {error}")
            return
        self.tally.add("quarantined", count)
        log.error("the database refused %d messages on their own merits (kept in %s): %s", count,
                  self.quarantine.path, err)
