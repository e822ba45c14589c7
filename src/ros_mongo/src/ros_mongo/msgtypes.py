"""Message classes for any type, and a message's decoded fields as plain queryable data.

A type is resolved to the installed genpy class when its md5sum matches; otherwise a class is
generated from the stored full definition (genpy.dynamic). Decoded fields are JSON/BSON-safe:
times become float seconds, non-finite floats the strings "NaN"/"Infinity"/"-Infinity", long byte
arrays and arrays longer than `max_array_len` become None (the exact serialized bytes are kept
beside the fields, so nothing is lost).
"""
import math
import threading
from typing import Any, Callable, Dict, List, Optional, Tuple

import genpy

from ros_mongo.errors import UnknownTypeError

__all__ = ["message_class", "decode", "to_fields", "header_stamp", "MAX_ARRAY_LEN"]

MAX_ARRAY_LEN = 4096
SMALL_BYTES_LEN = 64
INT64_MAX = 2 ** 63 - 1

_BYTE_TYPES = ("uint8", "char", "byte")
_TIME_TYPES = ("time", "duration")
_NUMERIC_TYPES = ("bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                  "float32", "float64", "byte", "char")
_lock = threading.Lock()
_classes: Dict[Tuple[str, str], type] = {}


def message_class(msg_type: str, md5sum: Optional[str] = None, definition: Optional[str] = None) -> type:
    """The genpy class for `msg_type` whose md5sum is `md5sum` (any md5sum when None).

    Raises:
        UnknownTypeError: the type is not installed (or has another md5sum) and no usable
            `definition` was given.
    """
    key = (msg_type, md5sum or "*")
    with _lock:
        cls = _classes.get(key)
    if cls is not None:
        return cls
    cls = _installed_class(msg_type)
    if cls is None or (md5sum and cls._md5sum != md5sum):
        cls = _generated_class(msg_type, md5sum, definition)
    with _lock:
        _classes[key] = cls
    return cls


def _installed_class(msg_type: str) -> Optional[type]:
    import roslib.message

    try:
        return roslib.message.get_message_class(msg_type)
    except Exception:  # noqa: BLE001 - roslib raises various errors for unknown packages
        return None


def _generated_class(msg_type: str, md5sum: Optional[str], definition: Optional[str]) -> type:
    if not definition:
        have = f" with md5sum {md5sum}" if md5sum else ""
        raise UnknownTypeError(f"message type {msg_type!r}{have} is not installed and no definition "
                               f"of it is stored")
    import genpy.dynamic

    try:
        cls = genpy.dynamic.generate_dynamic(msg_type, definition)[msg_type]
    except Exception as err:  # noqa: BLE001 - genmsg raises many kinds for bad text
        raise UnknownTypeError(f"cannot build message type {msg_type!r} from its stored definition: "
                               f"{err}") from err
    if md5sum and cls._md5sum != md5sum:
        raise UnknownTypeError(f"stored definition of {msg_type!r} gives md5sum {cls._md5sum}, "
                               f"messages have {md5sum}")
    return cls


def decode(cls: type, raw: bytes):
    """Deserialize `raw` into a new `cls` message (genpy errors become UnknownTypeError)."""
    try:
        return cls().deserialize(raw)
    except genpy.DeserializationError as err:
        raise UnknownTypeError(f"bytes do not decode as {cls._type}: {err}") from err
    except Exception as err:  # noqa: BLE001 - struct.error etc. from generated code
        raise UnknownTypeError(f"bytes do not decode as {cls._type}: {type(err).__name__}: {err}") from err


def header_stamp(msg) -> Optional[float]:
    """The header stamp in seconds for messages with a std_msgs/Header, else None."""
    if getattr(msg.__class__, "_has_header", False):
        return msg.header.stamp.to_sec()
    return None


def to_fields(msg, max_array_len: int = MAX_ARRAY_LEN) -> Dict[str, Any]:
    """The message as a dict of JSON/BSON-safe values (see the module docstring)."""
    return {name: convert(getattr(msg, name), max_array_len)
            for name, convert in _plan(msg.__class__)}


_plans: Dict[type, List[Tuple[str, Callable[[Any, int], Any]]]] = {}


def _plan(cls: type) -> List[Tuple[str, Callable[[Any, int], Any]]]:
    plan = _plans.get(cls)
    if plan is None:
        plan = [(name, _converter(slot_type)) for name, slot_type in zip(cls.__slots__, cls._slot_types)]
        _plans[cls] = plan
    return plan


def _converter(slot_type: str) -> Callable[[Any, int], Any]:
    if slot_type.endswith("]"):
        base = slot_type[:slot_type.index("[")]
        if base in _BYTE_TYPES:
            return _bytes_value
        if base in _TIME_TYPES:
            return _time_array
        if base in _NUMERIC_TYPES:
            return _number_array
        if base == "string":
            return _string_array
        return _message_array
    if slot_type in ("float32", "float64"):
        return _float_value
    if slot_type in _NUMERIC_TYPES:
        return _int_value
    if slot_type in _TIME_TYPES:
        return _time_value
    if slot_type == "string":
        return _string_value
    return _message_value


def _float_value(value, _limit):
    return value if math.isfinite(value) else _non_finite(value)


def _non_finite(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    return "Infinity" if value > 0 else "-Infinity"


def _int_value(value, _limit):
    if isinstance(value, bool) or not isinstance(value, int):
        return value if not isinstance(value, float) else _float_value(value, _limit)
    return value if -INT64_MAX - 1 <= value <= INT64_MAX else float(value)


def _time_value(value, _limit):
    return value.to_sec()


def _string_value(value, _limit):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return value.encode("utf-8", "replace").decode("utf-8")
    return value


def _message_value(value, limit):
    return to_fields(value, limit)


def _bytes_value(value, limit):
    if len(value) > min(limit, SMALL_BYTES_LEN):
        return None
    return list(bytearray(value)) if isinstance(value, (bytes, bytearray)) else list(value)


def _number_array(values, limit):
    if len(values) > limit:
        return None
    values = list(values)
    if not values:
        return values
    if isinstance(values[0], float):
        try:
            if math.isfinite(math.fsum(values)):
                return values
        except (OverflowError, ValueError):
            pass
        return [_float_value(v, limit) for v in values]
    if -INT64_MAX - 1 <= min(values) and max(values) <= INT64_MAX:
        return values
    return [_int_value(v, limit) for v in values]


def _time_array(values, limit):
    return None if len(values) > limit else [v.to_sec() for v in values]


def _string_array(values, limit):
    return None if len(values) > limit else [_string_value(v, limit) for v in values]


def _message_array(values, limit):
    return None if len(values) > limit else [to_fields(v, limit) for v in values]
