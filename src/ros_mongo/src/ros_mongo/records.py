"""What is stored: message records (one per message), topic infos (one per topic and type) and the
messages read back (StoredMessage)."""
import hashlib
import secrets
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence

import genpy

import ros_mongo.msgtypes as msgtypes
from ros_mongo.errors import UnknownTypeError

__all__ = ["TopicInfo", "MessageRecord", "StoredMessage", "make_record", "new_message_id",
           "split_time"]


@dataclass
class TopicInfo:
    """A topic's type, md5sum, full message definition and latching, kept once per topic+type."""

    topic: str
    msg_type: str
    md5sum: str
    definition: str
    latching: bool = False
    callerid: str = ""

    @property
    def id(self) -> str:
        key = f"{self.topic}\n{self.msg_type}\n{self.md5sum}".encode()
        return "topic-" + hashlib.sha1(key).hexdigest()[:24]

    @classmethod
    def of_class(cls, topic: str, msg_class: type, *, latching: bool = False) -> "TopicInfo":
        return cls(topic, msg_class._type, msg_class._md5sum, msg_class._full_text, latching)


@dataclass
class MessageRecord:
    """One message ready to store: metadata, decoded fields and the exact serialized bytes."""

    id: str
    topic: str
    msg_type: str
    md5sum: str
    raw: bytes
    receive_secs: int
    receive_nsecs: int
    header_stamp: Optional[float] = None
    fields: Optional[Dict[str, Any]] = None
    tags: List[str] = field(default_factory=list)
    session_id: Optional[str] = None
    robot_id: Optional[str] = None

    @property
    def receive_time(self) -> float:
        return self.receive_secs + self.receive_nsecs * 1e-9


def split_time(seconds: float) -> genpy.Time:
    """Float seconds as a genpy.Time (secs, nsecs)."""
    return genpy.Time.from_sec(seconds)


def new_message_id(receive_secs: int, receive_nsecs: int) -> str:
    """A unique document id that sorts by receive time."""
    return f"{receive_secs * 1000000000 + receive_nsecs:019d}-{secrets.token_hex(6)}"


def make_record(topic: str, msg_class: type, raw: bytes, *, receive: Optional[genpy.Time] = None,
                tags: Sequence[str] = (), session_id: Optional[str] = None,
                robot_id: Optional[str] = None, record_id: Optional[str] = None,
                message=None, max_array_len: int = msgtypes.MAX_ARRAY_LEN) -> MessageRecord:
    """A record for the serialized message `raw` of `msg_class` received at `receive`.

    The fields are decoded from `raw` (or taken from `message` when given); bytes that do not
    decode are still stored, with no fields.
    """
    receive = receive if receive is not None else split_time(time.time())
    if message is None:
        try:
            message = msgtypes.decode(msg_class, raw)
        except UnknownTypeError:
            message = None
    record = MessageRecord(
        id=record_id or new_message_id(receive.secs, receive.nsecs), topic=topic,
        msg_type=msg_class._type, md5sum=msg_class._md5sum, raw=bytes(raw),
        receive_secs=receive.secs, receive_nsecs=receive.nsecs,
        tags=[str(t) for t in tags], session_id=session_id, robot_id=robot_id)
    if message is not None:
        record.header_stamp = msgtypes.header_stamp(message)
        record.fields = msgtypes.to_fields(message, max_array_len)
    return record


class StoredMessage:
    """A message read back from a store (built by `documents.stored_message` from its document).

    Attributes: id, topic, msg_type, md5sum, receive_time (float s), receive_stamp (genpy.Time,
    exact), header_stamp (float s or None), tags, session_id, robot_id, fields (decoded, as
    stored), size (bytes); `raw` (exact serialized bytes, fetched on first use when kept apart)
    and `message()` (the genpy message).
    """

    __slots__ = ("id", "topic", "msg_type", "md5sum", "receive_stamp", "header_stamp", "tags",
                 "session_id", "robot_id", "fields", "size", "_raw", "_load_raw", "_resolve")

    def __init__(self, *, id: str, topic: str, msg_type: str, md5sum: str,
                 receive_stamp: genpy.Time, header_stamp: Optional[float], tags: Sequence[str],
                 session_id: Optional[str], robot_id: Optional[str], fields: Optional[Dict[str, Any]],
                 size: int, raw: Optional[bytes], load_raw: Callable[[str], bytes],
                 resolve: Callable[[str, str], type]):
        self.id = id
        self.topic = topic
        self.msg_type = msg_type
        self.md5sum = md5sum
        self.receive_stamp = receive_stamp
        self.header_stamp = header_stamp
        self.tags = list(tags)
        self.session_id = session_id
        self.robot_id = robot_id
        self.fields = fields
        self.size = size
        self._raw = raw
        self._load_raw = load_raw
        self._resolve = resolve

    @property
    def receive_time(self) -> float:
        return self.receive_stamp.to_sec()

    @property
    def raw(self) -> bytes:
        if self._raw is None:
            self._raw = self._load_raw(self.id)
        return self._raw

    def message_class(self) -> type:
        return self._resolve(self.msg_type, self.md5sum)

    def message(self):
        """The genpy message (UnknownTypeError if its type cannot be resolved)."""
        return msgtypes.decode(self.message_class(), self.raw)

    def __repr__(self) -> str:
        return (f"StoredMessage(id={self.id!r}, topic={self.topic!r}, type={self.msg_type!r}, "
                f"receive_time={self.receive_time:.9f}, size={self.size})")
