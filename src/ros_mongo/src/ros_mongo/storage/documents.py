"""The stored form of messages and topics, shared by both backends, and the one Query -> filter
translation.

Message document (one per message, id `records.new_message_id`: receive time in nanoseconds, 19
digits, then a random suffix, so ids sort by receive time):

    _id, kind="message", topic, type, md5sum, receive_time (float s), receive_secs, receive_nsecs,
    header_stamp (float s or null), tags (list), session_id, robot_id, callerid (the publisher),
    size (bytes), author (only when set: the original mongodb_api's `author`),
    msg (the decoded fields, or null), fields_dropped (true when msg was left out to fit),
    and the bytes: `raw` inline (CouchDB base64 / MongoDB binary) up to the blob threshold,
    else a CouchDB attachment `raw` or a GridFS file under the message id (MongoDB: blob=true).

Topic document (one per topic, type, md5sum, publisher and source, id `TopicInfo.id`:
"topic-" + a hash; a message belongs to the topic document with its topic, type, md5sum,
callerid and robot_id):

    _id, kind="topic", topic, type, md5sum, definition, latching, callerid, robot_id

Queries: `query_conditions` turns a `Query` into a list of `Condition`s on document fields (the
query's meaning, written once); `to_selector` writes them in the syntax CouchDB Mango selectors
and MongoDB filters share for every operator a Query can hold.

Conditions on decoded message fields ("msg.<path>") mean the same on both backends (the two
servers' own rules differ for missing fields, arrays, nulls and mixed types, so every operator is
spelled out with $or / $nor / $elemMatch / $type, which both evaluate alike):
- `$eq v`: the field equals v, or it is an array with an element equal to v (a value of another
  type never equals: 1 is not "1" nor true). `$eq null`: the field is missing or null.
- `$ne v`: not `$eq v` (a missing field is "not equal"; an array holding v is not).
- `$in [..]`: `$eq` one of them; `$nin [..]`: `$ne` every one of them.
- `$exists true`: the field holds a value (not null); `$exists false`: it is missing or null.
- Ranges (`$gt $gte $lt $lte`, and [low, high]): all bounds of one field hold for the field's value,
  or for one element of an array field; numbers compare with numbers only, strings with strings
  only. The stored encodings of non-finite floats count as numbers: "Infinity" is above and
  "-Infinity" below every finite number, "NaN" is in no range (as in IEEE 754).
"""
import math
from typing import Any, Callable, Dict, List, NamedTuple, Optional

import genpy

from ros_mongo.errors import StoreError
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, StoredMessage, TopicInfo

__all__ = ["META_KEYS", "Condition", "query_conditions", "to_selector", "message_doc", "topic_doc",
           "topic_from_doc", "stored_message"]

#: Top-level keys of a stored message besides the decoded fields ("msg") and the bytes ("raw").
META_KEYS = ("_id", "topic", "type", "md5sum", "receive_time", "receive_secs", "receive_nsecs",
             "header_stamp", "tags", "session_id", "robot_id", "callerid", "size", "author")


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
    if query.author:
        conditions.append(Condition("author", "$eq", query.author))
    if query.start_time is not None:
        conditions.append(Condition("receive_time", "$gte", query.start_time))
    if query.end_time is not None:
        conditions.append(Condition("receive_time", "$lte", query.end_time))
    for path, condition in query.fields.items():
        conditions.extend(Condition("msg." + path, op, value) for op, value in condition.items())
    return conditions


def to_selector(conditions: List[Condition]) -> Dict[str, Any]:
    """A Mango selector / MongoDB filter meaning the same on both: per metadata field `{op: value,
    ...}` (the plain value when its only condition is $eq); conditions on message fields
    ("msg.*", see the module doc) spelled out as one top-level `{"$or": [{"$and": [...]}]}` (a
    top-level "$and" beside other fields is refused by pouchdb-server's planner; this is not)."""
    by_field: Dict[str, Dict[str, Any]] = {}
    for condition in conditions:
        by_field.setdefault(condition.field, {})[condition.op] = condition.value
    selector: Dict[str, Any] = {}
    clauses: List[Dict[str, Any]] = []
    for name, ops in by_field.items():
        if name.startswith("msg."):
            clauses.extend(_field_clauses(name, ops))
        else:
            selector[name] = ops["$eq"] if list(ops) == ["$eq"] else ops
    if clauses:
        selector["$or"] = [{"$and": clauses}]
    return selector


_RANGE_OPS = ("$gt", "$gte", "$lt", "$lte")
_INFINITIES = (("Infinity", math.inf), ("-Infinity", -math.inf))


def _equal(name: str, value: Any) -> List[Dict[str, Any]]:
    """Alternatives that together mean "`name` equals `value`" (see the module doc)."""
    if value is None:
        return [{name: {"$exists": False}}, {name: {"$eq": None}}]
    return [{name: {"$eq": value}}, {name: {"$elemMatch": {"$eq": value}}}]


def _none_of(name: str, values: List[Any]) -> Dict[str, Any]:
    """"`name` equals none of `values`": a missing field qualifies (unless None is among them).
    Apache CouchDB fails every condition on a missing field, `$not`/`$nor` ones too, so the
    missing case is its own alternative (pouchdb-server and MongoDB agree either way)."""
    none = {"$nor": [alt for v in values for alt in _equal(name, v)]}
    if any(v is None for v in values):
        return none
    return {"$or": [{name: {"$exists": False}}, none]}


def _field_clauses(name: str, ops: Dict[str, Any]) -> List[Dict[str, Any]]:
    clauses: List[Dict[str, Any]] = []
    for op, value in ops.items():
        if op == "$eq":
            clauses.append({"$or": _equal(name, value)})
        elif op == "$ne":
            clauses.append(_none_of(name, [value]))
        elif op == "$in":
            clauses.append({"$or": [alt for v in value for alt in _equal(name, v)]} if value
                           else {"$or": [{name: {"$in": []}}]})  # matches nothing, on both
        elif op == "$nin":
            if value:
                clauses.append(_none_of(name, value))
        elif op == "$exists":  # holds a value: neither missing nor null
            clauses.append({"$nor" if value else "$or": _equal(name, None)})
    bounds = {op: ops[op] for op in _RANGE_OPS if op in ops}
    if bounds:
        clauses.append({"$or": _range(name, bounds)})
    return clauses


def _range(name: str, bounds: Dict[str, Any]) -> List[Dict[str, Any]]:
    kind = "string" if isinstance(next(iter(bounds.values())), str) else "number"
    typed = dict(bounds, **{"$type": kind})
    alternatives = [{name: typed}, {name: {"$elemMatch": typed}}]
    if kind == "number":
        for text, value in _INFINITIES:
            if all(_holds(value, op, bound) for op, bound in bounds.items()):
                alternatives += _equal(name, text)
    return alternatives


def _holds(value: float, op: str, bound: float) -> bool:
    return {"$gt": value > bound, "$gte": value >= bound, "$lt": value < bound,
            "$lte": value <= bound}[op]


def message_doc(record: MessageRecord) -> dict:
    """The stored form of a message record, without its bytes (the backend adds those)."""
    doc = {"_id": record.id, "kind": "message", "topic": record.topic, "type": record.msg_type,
            "md5sum": record.md5sum, "receive_time": record.receive_time,
            "receive_secs": record.receive_secs, "receive_nsecs": record.receive_nsecs,
            "header_stamp": record.header_stamp, "tags": list(record.tags),
            "session_id": record.session_id, "robot_id": record.robot_id,
            "callerid": record.callerid, "size": len(record.raw), "msg": record.fields}
    if record.author:
        doc["author"] = record.author
    return doc


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
                         raw=raw, load_raw=load_raw, resolve=resolve, callerid=doc.get("callerid") or "",
                         author=doc.get("author"))


def topic_doc(info: TopicInfo) -> dict:
    """The stored form of a topic info."""
    return {"_id": info.id, "kind": "topic", "topic": info.topic, "type": info.msg_type,
            "md5sum": info.md5sum, "definition": info.definition, "latching": info.latching,
            "callerid": info.callerid, "robot_id": info.robot_id}


def topic_from_doc(doc: dict) -> TopicInfo:
    """A topic info read back from its stored form."""
    return TopicInfo(topic=doc["topic"], msg_type=doc["type"], md5sum=doc["md5sum"],
                     definition=doc.get("definition", ""), latching=bool(doc.get("latching", False)),
                     callerid=doc.get("callerid") or "", robot_id=doc.get("robot_id") or "")
