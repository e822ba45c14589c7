"""The stored form of messages and topics, shared by both backends, and the one Query -> filter
translation.

Message document (one per message, id `records.new_message_id`: receive time in nanoseconds, 19
digits, then a random suffix, so ids sort by receive time):

    _id, kind="message", topic, type, md5sum, receive_time (float s), receive_secs, receive_nsecs,
    header_stamp (float s or null), tags (list), session_id, robot_id, size (bytes),
    msg (the decoded fields, or null), fields_dropped (true when msg was left out to fit),
    and the bytes: `raw` inline (CouchDB base64 / MongoDB binary) up to the blob threshold,
    else a CouchDB attachment `raw` or a GridFS file under the message id (MongoDB: blob=true).

Topic document (one per topic, type and md5sum, id `TopicInfo.id`: "topic-" + a hash):

    _id, kind="topic", topic, type, md5sum, definition, latching, callerid

Queries: `query_conditions` turns a `Query` into a list of `Condition`s on document fields (the
query's meaning, written once); `to_selector` writes them in the syntax CouchDB Mango selectors
and MongoDB filters share for every operator a Query can hold.
"""
from typing import Any, Callable, Dict, List, NamedTuple, Optional

import genpy

from ros_mongo.errors import StoreError
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, StoredMessage, TopicInfo

__all__ = ["META_KEYS", "Condition", "query_conditions", "to_selector", "message_doc", "topic_doc",
           "topic_from_doc", "stored_message"]

#: Top-level keys of a stored message besides the decoded fields ("msg") and the bytes ("raw").
META_KEYS = ("_id", "topic", "type", "md5sum", "receive_time", "receive_secs", "receive_nsecs",
             "header_stamp", "tags", "session_id", "robot_id", "size")


class Condition(NamedTuple):
    """One condition on a document field: `op` is a query operator ($eq, $in, $all, $gte, ...)."""

    field: str
    op: str
    value: Any


def query_conditions(query: Query) -> List[Condition]:
    """Every condition a stored message must meet to match `query`, in a fixed order."""
    conditions: List[Condition] = []
    if query.topics:
        if len(query.topics) == 1:
            conditions.append(Condition("topic", "$eq", query.topics[0]))
        else:
            conditions.append(Condition("topic", "$in", list(query.topics)))
    if query.msg_type:
        conditions.append(Condition("type", "$eq", query.msg_type))
    if query.tags:
        conditions.append(Condition("tags", "$all", list(query.tags)))
    if query.session_id:
        conditions.append(Condition("session_id", "$eq", query.session_id))
    if query.robot_id:
        conditions.append(Condition("robot_id", "$eq", query.robot_id))
    if query.start_time is not None:
        conditions.append(Condition("receive_time", "$gte", query.start_time))
    if query.end_time is not None:
        conditions.append(Condition("receive_time", "$lte", query.end_time))
    for path, condition in query.fields.items():
        conditions.extend(Condition("msg." + path, op, value) for op, value in condition.items())
    return conditions


def to_selector(conditions: List[Condition]) -> Dict[str, Any]:
    """A Mango selector / MongoDB filter: per field, `{op: value, ...}`, or the plain value when
    the field's only condition is $eq (both databases read a plain value as $eq)."""
    by_field: Dict[str, Dict[str, Any]] = {}
    for condition in conditions:
        by_field.setdefault(condition.field, {})[condition.op] = condition.value
    return {name: ops["$eq"] if list(ops) == ["$eq"] else ops for name, ops in by_field.items()}


def message_doc(record: MessageRecord) -> dict:
    """The stored form of a message record, without its bytes (the backend adds those)."""
    return {"_id": record.id, "kind": "message", "topic": record.topic, "type": record.msg_type,
            "md5sum": record.md5sum, "receive_time": record.receive_time,
            "receive_secs": record.receive_secs, "receive_nsecs": record.receive_nsecs,
            "header_stamp": record.header_stamp, "tags": list(record.tags),
            "session_id": record.session_id, "robot_id": record.robot_id,
            "size": len(record.raw), "msg": record.fields}


def stored_message(doc: Dict[str, Any], raw: Optional[bytes], load_raw: Callable[[str], bytes],
                   resolve: Callable[[str, str], type]) -> StoredMessage:
    """A message document read back (StoreError when `doc` is not a stored message)."""
    try:
        identity = dict(id=str(doc["_id"]), topic=doc["topic"], msg_type=doc["type"],
                        md5sum=doc["md5sum"],
                        receive_stamp=genpy.Time(int(doc["receive_secs"]), int(doc["receive_nsecs"])))
    except (KeyError, TypeError, ValueError) as err:
        raise StoreError(f"document {doc.get('_id')!r} is not a stored message: {err!r}") from err
    return StoredMessage(**identity, header_stamp=doc.get("header_stamp"), tags=doc.get("tags") or [],
                         session_id=doc.get("session_id"), robot_id=doc.get("robot_id"),
                         fields=doc.get("msg"), size=int(doc.get("size", len(raw) if raw is not None else 0)),
                         raw=raw, load_raw=load_raw, resolve=resolve)


def topic_doc(info: TopicInfo) -> dict:
    """The stored form of a topic info."""
    return {"_id": info.id, "kind": "topic", "topic": info.topic, "type": info.msg_type,
            "md5sum": info.md5sum, "definition": info.definition, "latching": info.latching,
            "callerid": info.callerid}


def topic_from_doc(doc: dict) -> TopicInfo:
    """A topic info read back from its stored form."""
    return TopicInfo(topic=doc["topic"], msg_type=doc["type"], md5sum=doc["md5sum"],
                     definition=doc.get("definition", ""), latching=bool(doc.get("latching", False)),
                     callerid=doc.get("callerid", ""))
