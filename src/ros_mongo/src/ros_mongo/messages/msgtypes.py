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

__all__ = ["message_class", "decode", "decode_scratch", "to_fields", "index_fields", "header_stamp",
           "MAX_ARRAY_LEN", "reference_fields", "reference_index_fields"]

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


_scratch = threading.local()


def decode_scratch(cls: type, raw: bytes):
    """`decode` into a message object kept for this thread and class, overwritten by the next
    call: for converting to fields at once (no new object per message; genpy's constructor
    builds every nested message and time)."""
    objects = getattr(_scratch, "objects", None)
    if objects is None:
        objects = _scratch.objects = {}
    msg = objects.get(cls)
    if msg is None:
        msg = objects[cls] = cls()
    try:
        return msg.deserialize(raw)
    except genpy.DeserializationError as err:
        objects.pop(cls, None)  # half-written: start the next one afresh
        raise UnknownTypeError(f"bytes do not decode as {cls._type}: {err}") from err
    except Exception as err:  # noqa: BLE001 - struct.error etc. from generated code
        objects.pop(cls, None)
        raise UnknownTypeError(f"bytes do not decode as {cls._type}: {type(err).__name__}: {err}") from err


def header_stamp(msg) -> Optional[float]:
    """The header stamp in seconds for messages with a std_msgs/Header, else None."""
    if getattr(msg.__class__, "_has_header", False):
        return msg.header.stamp.to_sec()
    return None


def to_fields(msg, max_array_len: int = MAX_ARRAY_LEN) -> Dict[str, Any]:
    """The message as a dict of JSON/BSON-safe values (see the module docstring)."""
    return _compiled(msg.__class__, False)(msg, max_array_len)


def index_fields(msg) -> Dict[str, Any]:
    """The message's fields without any array (ros_mongo.messages.decoding's `index` level)."""
    return _compiled(msg.__class__, True)(msg, 0)


def reference_fields(msg, max_array_len: int = MAX_ARRAY_LEN) -> Dict[str, Any]:
    """`to_fields` the slow, generic way (one converter call per field): the reference the
    compiled converters are tested against, and their way for values they do not take."""
    return {name: convert(getattr(msg, name), max_array_len)
            for name, convert in _plan(msg.__class__)}


def reference_index_fields(msg, _max_array_len: int = 0) -> Dict[str, Any]:
    """`index_fields` the slow, generic way (see `reference_fields`)."""
    return {name: convert(getattr(msg, name), 0) for name, convert in _index_plan(msg.__class__)}


# -- compiled converters: one generated function per message class and level ------------------------
# A message's fields as one dict expression over its attributes (nested messages inlined), so a
# 1 kHz Odometry costs one call instead of one per field. Floats are passed through when their sum
# is finite (no NaN or infinity anywhere); otherwise the reference converter handles the message.

_compiled_functions: Dict[Tuple[type, bool], Callable[[Any, int], Dict[str, Any]]] = {}
_INT64_TYPES = ("int64", "uint64")


def _compiled(cls: type, index: bool) -> Callable[[Any, int], Dict[str, Any]]:
    function = _compiled_functions.get((cls, index))
    if function is None:
        function = _compile(cls, index)
        _compiled_functions[(cls, index)] = function
    return function


def _compile(cls: type, index: bool) -> Callable[[Any, int], Dict[str, Any]]:
    names: Dict[str, Any] = {"_isfinite": math.isfinite, "_fsum": math.fsum, "_int_value": _int_value,
                             "_string_value": _string_value,
                             "_slow": reference_index_fields if index else reference_fields}
    floats: List[str] = []

    def expression(path: str, slot_type: str, sample) -> Optional[str]:
        if slot_type.endswith("]"):
            if index:
                return None
            names[f"_array{len(names)}"] = _converter(slot_type)
            return f"_array{len(names) - 1}({path}, limit)"
        if slot_type in ("float32", "float64"):
            floats.append(path)
            return path
        if slot_type in _INT64_TYPES:
            return f"_int_value({path}, limit)"
        if slot_type in _NUMERIC_TYPES:
            return path
        if slot_type in _TIME_TYPES:
            return f"({path}.secs + {path}.nsecs / 1e9)"  # = genpy's to_sec()
        if slot_type == "string":
            return f"_string_value({path}, limit)"
        return _message(path, sample)

    def _message(path: str, sample) -> str:
        items = []
        for name, slot_type in zip(sample.__slots__, sample._slot_types):
            value = expression(f"{path}.{name}", slot_type, getattr(sample, name))
            if value is not None:
                items.append(f"{name!r}: {value}")
        return "{" + ", ".join(items) + "}"

    body = _message("m", cls())
    check = ""
    if floats:
        check = (f"    try:\n        finite = _isfinite(_fsum(({', '.join(floats)},)))\n"
                 f"    except (OverflowError, ValueError):\n        finite = False\n"
                 f"    if not finite:\n        return _slow(m, limit)\n")
    source = f"def fields(m, limit):\n{check}    return {body}\n"
    exec(compile(source, f"<ros_mongo fields of {cls._type}>", "exec"), names)  # noqa: S102 - our own text
    return names["fields"]


_plans: Dict[type, List[Tuple[str, Callable[[Any, int], Any]]]] = {}
_index_plans: Dict[type, List[Tuple[str, Callable[[Any, int], Any]]]] = {}


def _plan(cls: type) -> List[Tuple[str, Callable[[Any, int], Any]]]:
    plan = _plans.get(cls)
    if plan is None:
        plan = [(name, _converter(slot_type)) for name, slot_type in zip(cls.__slots__, cls._slot_types)]
        _plans[cls] = plan
    return plan


def _index_plan(cls: type) -> List[Tuple[str, Callable[[Any, int], Any]]]:
    plan = _index_plans.get(cls)
    if plan is None:
        plan = [(name, _index_message if converter is _message_value else converter)
                for (name, converter), slot_type in zip(_plan(cls), cls._slot_types)
                if not slot_type.endswith("]")]
        _index_plans[cls] = plan
    return plan


def _index_message(value, _limit):
    return reference_index_fields(value)


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
    return reference_fields(value, limit)


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
    return None if len(values) > limit else [to_fields(v, limit) for v in values]  # (compiled)
