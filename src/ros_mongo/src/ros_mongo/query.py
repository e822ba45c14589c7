"""Queries over stored messages: one validated form for both backends, parsed from keywords or text.

Message-field conditions use the operators CouchDB Mango and MongoDB share: a plain value means
equality, a mapping may use $eq $ne $gt $gte $lt $lte $in $nin $exists, and a two-element list
[low, high] means low <= value <= high. Field paths are dotted ("header.frame_id",
"pose.pose.position.x", "ranges.0"). What each operator matches (missing fields, arrays, nulls,
"NaN"/"Infinity") is defined once, the same for both backends: see `ros_mongo.storage.documents`.
Range bounds are numbers or strings, all of one kind per field.
"""
import logging
import math
import re
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Union

from ros_mongo.errors import QueryError

__all__ = ["Query", "parse_query", "QUERY_KEYS", "original_words"]

log = logging.getLogger(__name__)

OPERATORS = ("$eq", "$ne", "$gt", "$gte", "$lt", "$lte", "$in", "$nin", "$exists")
QUERY_KEYS = ("topic", "topics", "type", "msg_type", "tags", "session_id", "robot_id", "author",
              "start_time", "end_time", "fields")
#: keys whose value in the original "<key> <value>" form is a list
_LIST_KEYS = ("tags", "topic", "topics")
_TIME_KEYS = ("start_time", "end_time")
#: the original form's word separators: what is not a letter, digit or "_" (as the original's
#: re.sub('[^\\w]', ' ', query)), except "/", "." and "-", which today's values hold (topic and
#: type names, times, session ids)
_SEPARATORS = re.compile(r"[^\w/.\-]+")
_PATH = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.([A-Za-z_][A-Za-z0-9_]*|[0-9]+))*$")
_SCALARS = (str, int, float, bool, type(None))


@dataclass
class Query:
    """Which messages: every given criterion must hold (tags: the message has all of them)."""

    topics: Optional[List[str]] = None
    msg_type: Optional[str] = None
    tags: Optional[List[str]] = None
    session_id: Optional[str] = None
    robot_id: Optional[str] = None
    start_time: Optional[float] = None
    end_time: Optional[float] = None
    fields: Dict[str, Dict[str, Any]] = field(default_factory=dict)
    author: Optional[str] = None

    @classmethod
    def build(cls, *, topic: Union[str, Sequence[str], None] = None, msg_type: Optional[str] = None,
              tags: Union[str, Sequence[str], None] = None, session_id: Optional[str] = None,
              robot_id: Optional[str] = None, start_time: Optional[float] = None,
              end_time: Optional[float] = None, fields: Optional[Dict[str, Any]] = None,
              author: Optional[str] = None) -> "Query":
        """A validated query (QueryError names the offending value)."""
        query = cls(topics=_names("topic", topic), msg_type=_text("type", msg_type),
                    tags=_names("tags", tags), session_id=_text("session_id", session_id),
                    robot_id=_text("robot_id", robot_id), start_time=_time("start_time", start_time),
                    end_time=_time("end_time", end_time), fields=_fields(fields),
                    author=_text("author", author))
        if query.start_time is not None and query.end_time is not None \
                and query.start_time > query.end_time:
            raise QueryError(f"start_time {query.start_time} is after end_time {query.end_time}")
        return query

    def with_times(self, start_time: Optional[float], end_time: Optional[float]) -> "Query":
        """A copy with the time range narrowed to [start_time, end_time]."""
        starts = [t for t in (self.start_time, start_time) if t is not None]
        ends = [t for t in (self.end_time, end_time) if t is not None]
        return Query(self.topics, self.msg_type, self.tags, self.session_id, self.robot_id,
                     max(starts) if starts else None, min(ends) if ends else None, dict(self.fields),
                     self.author)

    def describe(self) -> str:
        parts = [f"{key}={value!r}" for key, value in self.__dict__.items() if value not in (None, {}, [])]
        return ", ".join(parts) or "all messages"


def parse_query(text: str) -> Query:
    """A query from text: a YAML/JSON mapping of QUERY_KEYS, or the original form "<key> <value>"
    ("tags lidar", "author ServiceRobot", also "tags:lidar", "tags=lidar"): punctuation separates
    words and words after the first two are ignored (with a warning), as the original did; empty
    text means all messages."""
    import yaml

    text = (text or "").strip()
    if not text:
        return Query()
    structured = text[0] in "{["  # meant as YAML/JSON: its errors are reported, not re-read as words
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        if structured:
            raise QueryError(f"query is neither a YAML/JSON mapping nor '<key> <value>': {text!r} "
                             f"({str(err).splitlines()[0]})") from None
        data = None
    if isinstance(data, dict):
        return query_from_mapping(data)
    if structured:
        raise QueryError(f"query must be a mapping of {', '.join(QUERY_KEYS)} "
                         f"(or '<key> <value>'), got {text!r}")
    words = original_words(text)
    if len(words) < 2:
        raise QueryError(f"query must be a YAML/JSON mapping of {', '.join(QUERY_KEYS)} or "
                         f"'<key> <value>' (e.g. 'tags lidar'), got {text!r}")
    if len(words) > 2:
        log.warning("query %r: words after the first two ignored, as the original did: %s", text,
                    " ".join(words[2:]))
    return _original_form(words[0], words[1])


def original_words(text: str) -> List[str]:
    """The words of an original-form query: punctuation (but "/", ".", "-") separates words."""
    return _SEPARATORS.sub(" ", text or "").split()


def _original_form(key: str, value: str) -> Query:
    if key not in QUERY_KEYS or key == "fields":
        raise QueryError(f"unknown query key {key!r} in '<key> <value>'; known: "
                         f"{', '.join(k for k in QUERY_KEYS if k != 'fields')}")
    if key in _TIME_KEYS:
        try:
            return query_from_mapping({key: float(value)})
        except ValueError:
            raise QueryError(f"{key} must be a number of seconds, got {value!r}") from None
    return query_from_mapping({key: [value] if key in _LIST_KEYS else value})


def query_from_mapping(data: Dict[str, Any]) -> Query:
    """A query from a mapping with QUERY_KEYS (e.g. a ROS parameter dict)."""
    unknown = sorted(str(k) for k in data if k not in QUERY_KEYS)
    if unknown:
        raise QueryError(f"unknown query key(s) {unknown}; known: {', '.join(QUERY_KEYS)}")
    topics = data.get("topics", data.get("topic"))
    return Query.build(topic=topics, msg_type=data.get("type", data.get("msg_type")),
                       tags=data.get("tags"), session_id=data.get("session_id"),
                       robot_id=data.get("robot_id"), start_time=data.get("start_time"),
                       end_time=data.get("end_time"), fields=data.get("fields"),
                       author=data.get("author"))


def _text(name: str, value) -> Optional[str]:
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise QueryError(f"{name} must be a string, got {value!r}")
    return value


def _names(name: str, value) -> Optional[List[str]]:
    if value is None or value == "" or value == []:
        return None
    values = [value] if isinstance(value, str) else value
    if not isinstance(values, (list, tuple, set)) or not all(isinstance(v, str) and v for v in values):
        raise QueryError(f"{name} must be a string or a list of non-empty strings, got {value!r}")
    return list(values)


def _time(name: str, value) -> Optional[float]:
    if value is None or value == "":
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise QueryError(f"{name} must be a finite number of seconds, got {value!r}")
    return float(value)


def _fields(value) -> Dict[str, Dict[str, Any]]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise QueryError(f"fields must be a mapping of field path to condition, got {value!r}")
    return {_path(path): _condition(path, cond) for path, cond in value.items()}


def _path(path) -> str:
    if not isinstance(path, str) or not _PATH.match(path):
        raise QueryError(f"bad field path {path!r}: use dotted field names like 'header.frame_id'")
    return path


def _condition(path: str, cond) -> Dict[str, Any]:
    if isinstance(cond, _SCALARS):
        return {"$eq": _scalar(path, cond)}
    if isinstance(cond, (list, tuple)):
        if len(cond) != 2:
            raise QueryError(f"field {path!r}: a list condition must be [low, high], got {cond!r}")
        bounds = {"$gte": _scalar(path, cond[0]), "$lte": _scalar(path, cond[1])}
        _check_range(path, bounds)
        return bounds
    if not isinstance(cond, dict) or not cond:
        raise QueryError(f"field {path!r}: condition must be a value, [low, high] or an operator "
                         f"mapping, got {cond!r}")
    out = {}
    for op, operand in cond.items():
        if op not in OPERATORS:
            raise QueryError(f"field {path!r}: unknown operator {op!r}; use one of {', '.join(OPERATORS)}")
        if op in ("$in", "$nin"):
            if not isinstance(operand, (list, tuple)):
                raise QueryError(f"field {path!r}: {op} needs a list, got {operand!r}")
            out[op] = [_scalar(path, v) for v in operand]
        elif op == "$exists":
            if not isinstance(operand, bool):
                raise QueryError(f"field {path!r}: $exists needs true or false, got {operand!r}")
            out[op] = operand
        else:
            out[op] = _scalar(path, operand)
    _check_range(path, out)
    return out


def _check_range(path: str, cond: Dict[str, Any]) -> None:
    bounds = [cond[op] for op in ("$gt", "$gte", "$lt", "$lte") if op in cond]
    kinds = {"string" if isinstance(b, str) else "number" if isinstance(b, (int, float))
             and not isinstance(b, bool) else repr(b) for b in bounds}
    if kinds - {"string", "number"} or len(kinds) > 1:
        raise QueryError(f"field {path!r}: range bounds must all be numbers or all strings, got {bounds!r}")


def _scalar(path: str, value):
    if not isinstance(value, _SCALARS):
        raise QueryError(f"field {path!r}: compare with a number, string, boolean or null, got {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise QueryError(f"field {path!r}: non-finite number {value!r} in a query")
    return value
