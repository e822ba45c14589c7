"""What is stored: message records (one per message), topic infos (one per topic, type, publisher
and source) and the messages read back (StoredMessage).

Ids never conflict between robots or bags sharing one database:
- a message id is `<receive time in ns, 19 digits>-<robot id, escaped>-<12 hex digits>`
  (`new_message_id`); the time prefix makes ids sort by receive time (the MongoDB backend relies
  on it), the robot id makes two robots' ids differ even for the same nanosecond;
- a topic info is kept per (topic, type, md5sum, callerid, source), where the source is the robot
  id (recording) or the bag's session (import), so every publisher of /tf and every robot keeps
  its own latching, callerid and definition (first writer wins only within one such key).
"""
import hashlib
import itertools
import re
import secrets
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence

import genpy

import ros_mongo.messages.msgtypes as msgtypes
from ros_mongo.errors import UnknownTypeError
from ros_mongo.messages.decoding import stamp_from_bytes

__all__ = ["TopicInfo", "MessageRecord", "StoredMessage", "make_record", "record_from_bytes",
           "new_message_id", "split_time", "id_part"]

_UNSAFE = re.compile(r"[^A-Za-z0-9._~]")


@dataclass
class TopicInfo:
    """A topic's type, md5sum, full message definition, latching and publisher (callerid), kept
    once per (topic, type, md5sum, callerid, robot_id); `robot_id` is the source: the recording
    robot, or the session of an imported bag."""

    topic: str
    msg_type: str
    md5sum: str
    definition: str
    latching: bool = False
    callerid: str = ""
    robot_id: str = ""

    @property
    def key(self) -> tuple:
        return (self.topic, self.msg_type, self.md5sum, self.callerid, self.robot_id)

    @property
    def id(self) -> str:
        key = f"{self.topic}\n{self.msg_type}\n{self.md5sum}"
        if self.callerid or self.robot_id:
            key += f"\n{self.callerid}\n{self.robot_id}"
        return "topic-" + hashlib.sha1(key.encode()).hexdigest()[:24]

    @classmethod
    def of_class(cls, topic: str, msg_class: type, *, latching: bool = False, callerid: str = "",
                 robot_id: str = "") -> "TopicInfo":
        return cls(topic, msg_class._type, msg_class._md5sum, msg_class._full_text, latching,
                   callerid, robot_id or "")


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
    callerid: str = ""   # the publisher (with robot_id: which TopicInfo the message belongs to)
    author: Optional[str] = None   # who recorded it (the original mongodb_api's `author`)

    @property
    def receive_time(self) -> float:
        return self.receive_secs + self.receive_nsecs * 1e-9


def split_time(seconds: float) -> genpy.Time:
    """Float seconds as a genpy.Time (secs, nsecs)."""
    return genpy.Time.from_sec(seconds)


def id_part(text: Optional[str]) -> str:
    """`text` as a part of a document id: letters, digits and ._~ kept, others %XX (so distinct
    texts give distinct parts, and '-' never appears: it separates the parts)."""
    return _UNSAFE.sub(lambda m: "".join(f"%{b:02X}" for b in m.group(0).encode("utf-8")), text or "")


#: Default id tokens: a random 48-bit start per process, counting up (one system call per process
#: instead of one per message; two processes share a token only if their random starts are
#: within a few million of each other, and then they would still need the same nanosecond).
_TOKENS = itertools.count(secrets.randbits(48))


def new_message_id(receive_secs: int, receive_nsecs: int, robot_id: Optional[str] = None, *,
                   token: Optional[str] = None) -> str:
    """A unique document id that sorts by receive time: `<ns, 19 digits>-<robot>-<token>`
    (`<ns>-<token>` without a robot id); `token` defaults to 12 hex digits, unique within this
    process and random across processes."""
    token = token or f"{next(_TOKENS) & 0xFFFFFFFFFFFF:012x}"
    stamp = f"{receive_secs * 1000000000 + receive_nsecs:019d}"
    return f"{stamp}-{id_part(robot_id)}-{token}" if robot_id else f"{stamp}-{token}"


def make_record(topic: str, msg_class: type, raw: bytes, *, receive: Optional[genpy.Time] = None,
                tags: Sequence[str] = (), session_id: Optional[str] = None,
                robot_id: Optional[str] = None, record_id: Optional[str] = None,
                message=None, max_array_len: int = msgtypes.MAX_ARRAY_LEN,
                callerid: str = "", author: Optional[str] = None, decode: str = "full") -> MessageRecord:
    """A record for the serialized message `raw` of `msg_class` received at `receive`.

    The fields are decoded from `raw` (or taken from `message` when given) at the `decode` level
    (ros_mongo.messages.decoding: full, index or raw); bytes that do not decode are still stored, with no
    fields.
    """
    receive = receive if receive is not None else split_time(time.time())
    return record_from_bytes(topic, msg_class, raw, receive.secs, receive.nsecs, tags=[str(t) for t in tags],
                             session_id=session_id, robot_id=robot_id, record_id=record_id, message=message,
                             max_array_len=max_array_len, callerid=callerid, author=author, decode=decode)


def record_from_bytes(topic: str, msg_class: type, raw: bytes, secs: int, nsecs: int, *,
                      tags: List[str], session_id: Optional[str], robot_id: Optional[str],
                      record_id: Optional[str] = None, message=None,
                      max_array_len: int = msgtypes.MAX_ARRAY_LEN, callerid: str = "",
                      author: Optional[str] = None, decode: str = "full") -> MessageRecord:
    """`make_record` for the recorder's hot path: the receive time as (secs, nsecs), `tags` a
    list of strings kept as given; decoding reuses one message object per thread and class."""
    record = MessageRecord(
        id=record_id or new_message_id(secs, nsecs, robot_id), topic=topic, msg_type=msg_class._type,
        md5sum=msg_class._md5sum, raw=bytes(raw), receive_secs=secs, receive_nsecs=nsecs, tags=tags,
        session_id=session_id, robot_id=robot_id, callerid=callerid or "", author=author or None)
    if decode == "raw":
        if getattr(msg_class, "_has_header", False):
            record.header_stamp = stamp_from_bytes(record.raw)
        return record
    if message is None:
        try:
            message = msgtypes.decode_scratch(msg_class, raw)
        except UnknownTypeError:
            message = None
    if message is not None:
        record.header_stamp = msgtypes.header_stamp(message)
        record.fields = (msgtypes.index_fields(message) if decode == "index"
                         else msgtypes.to_fields(message, max_array_len))
    return record


class StoredMessage:
    """A message read back from a store (built by `documents.stored_message` from its document).

    Attributes: id, topic, msg_type, md5sum, receive_time (float s), receive_stamp (genpy.Time,
    exact), header_stamp (float s or None), tags, session_id, robot_id, fields (decoded, as
    stored), size (bytes), callerid (the publisher, "" if unknown), author (or None); `raw` (exact serialized
    bytes, fetched on first use when kept apart) and `message()` (the genpy message).
    """

    __slots__ = ("id", "topic", "msg_type", "md5sum", "receive_stamp", "header_stamp", "tags",
                 "session_id", "robot_id", "fields", "size", "_raw", "_load_raw", "_resolve", "callerid",
                 "author")

    def __init__(self, *, id: str, topic: str, msg_type: str, md5sum: str,
                 receive_stamp: genpy.Time, header_stamp: Optional[float], tags: Sequence[str],
                 session_id: Optional[str], robot_id: Optional[str], fields: Optional[Dict[str, Any]],
                 size: int, raw: Optional[bytes], load_raw: Callable[[str], bytes],
                 resolve: Callable[[str, str], type], callerid: str = "",
                 author: Optional[str] = None):
        self.id = id
        self.author = author
        self.callerid = callerid
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
