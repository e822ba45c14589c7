"""The recorder's records from received bytes (no ROS): each topic's message class, installed or
generated from the definition its publisher sent, the topic's decode level (ros_mongo.messages.decoding),
the tags and ids every message carries."""
import logging
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import genpy

import ros_mongo.messages.msgtypes as msgtypes
from ros_mongo.errors import UnknownTypeError
from ros_mongo.messages.decoding import DecodePolicy
from ros_mongo.records import MessageRecord, TopicInfo, make_record, new_message_id, record_from_bytes
from ros_mongo.storage.chunks import ChunkRecord

__all__ = ["RecordBuilder", "Key"]

log = logging.getLogger(__name__)
Key = Tuple[str, str, str, str]  # topic, type, md5sum, publisher (callerid)


class RecordBuilder:
    """Builds the records of received messages.

    Args:
        topics: the topic infos by key, shared with the recorder (which adds each new topic).
        decode: the decode level per topic / type.
        tags, topic_tags, session_id, robot_id, author: stored with every message.
        max_array_len: longer arrays are not decoded into the queryable fields.
    """

    def __init__(self, topics: Dict[Key, TopicInfo], *, decode: DecodePolicy, tags: Sequence[str] = (),
                 topic_tags: Optional[Mapping[str, Sequence[str]]] = None, session_id: Optional[str] = None,
                 robot_id: Optional[str] = None, author: Optional[str] = None,
                 max_array_len: int = msgtypes.MAX_ARRAY_LEN):
        self.topics, self.decode = topics, decode
        self.tags = [str(t) for t in tags]
        self.topic_tags = {topic: [str(t) for t in values] for topic, values in (topic_tags or {}).items()}
        self.session_id, self.robot_id, self.author = session_id, robot_id, author or None
        self.max_array_len = int(max_array_len)
        self._classes: Dict[Key, Optional[type]] = {}

    def record(self, key: Key, raw: bytes, secs: int, nsecs: int) -> MessageRecord:
        """The record of one message, decoded at its topic's level."""
        cls = self.message_class(key)
        if cls is None:
            return self.raw(key, raw, secs, nsecs)
        return record_from_bytes(key[0], cls, raw, secs, nsecs, tags=self._tags_of(key[0]),
                                 session_id=self.session_id, robot_id=self.robot_id,
                                 max_array_len=self.max_array_len, callerid=key[3], author=self.author,
                                 decode=self.decode.level(key[0], key[1]))

    def raw(self, key: Key, raw: bytes, secs: int, nsecs: int) -> MessageRecord:
        """The record of one message without decoding it (`complete` decodes it later)."""
        return MessageRecord(new_message_id(secs, nsecs, self.robot_id), key[0], key[1], key[2], raw,
                             secs, nsecs, tags=self._tags_of(key[0]), session_id=self.session_id,
                             robot_id=self.robot_id, callerid=key[3], author=self.author)

    def complete(self, entries: list) -> None:
        """Decode the fields of spooled records that went to the spool undecoded (topic infos
        among `entries` are learnt: the spool may come from an earlier recorder)."""
        flat: list = []
        for entry in entries:
            flat.extend(entry.records if isinstance(entry, ChunkRecord) else [entry])
        for entry in flat:
            if isinstance(entry, TopicInfo):
                self.topics.setdefault((entry.topic, entry.msg_type, entry.md5sum, entry.callerid), entry)
            elif entry.fields is None and entry.header_stamp is None:
                key = (entry.topic, entry.msg_type, entry.md5sum, entry.callerid)
                cls = self.message_class(key) if key in self.topics else None
                if cls is not None:
                    done = make_record(entry.topic, cls, entry.raw, record_id=entry.id,
                                       receive=genpy.Time(entry.receive_secs, entry.receive_nsecs),
                                       max_array_len=self.max_array_len,
                                       decode=self.decode.level(entry.topic, entry.msg_type))
                    entry.header_stamp, entry.fields = done.header_stamp, done.fields

    def message_class(self, key: Key) -> Optional[type]:
        """The class of a topic's messages; None (stored without fields, once warned) when its
        type is neither installed nor described by a usable definition."""
        if key not in self._classes:
            info = self.topics[key]
            try:
                self._classes[key] = msgtypes.message_class(info.msg_type, info.md5sum, info.definition)
            except UnknownTypeError as err:
                log.warning("storing %s without decoded fields: %s", info.topic, err)
                self._classes[key] = None
        return self._classes[key]

    def _tags_of(self, topic: str) -> List[str]:
        return self.tags + self.topic_tags.get(topic, [])
