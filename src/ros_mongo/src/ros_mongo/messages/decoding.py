"""How much of each message the recorder decodes into queryable fields (no ROS).

The exact serialized bytes are always stored; the decoded fields (`msg` in the stored document)
are only for queries. Three levels, chosen per topic or per message type:

- `full`: every field (arrays longer than `max_array_len` and byte arrays longer than 64 bytes
  are left out as null, as always);
- `index`: every field except arrays (header, scalars, nested messages' scalars: e.g. an image's
  header, height, width, encoding and step; a scan's header, angles and range limits; odometry's
  pose and twist without their covariances). Array fields are absent from `msg`;
- `raw`: no fields (`msg` is null); `header_stamp` is still filled, read straight from the bytes
  for types with a std_msgs/Header.

Metadata (topic, type, receive time, header_stamp, tags, session, robot, size) is stored and
queryable at every level.
"""
import struct
from typing import Dict, Mapping, Optional

__all__ = ["DECODE_LEVELS", "DecodePolicy", "stamp_from_bytes"]

DECODE_LEVELS = ("full", "index", "raw")
_STAMP = struct.Struct("<3I")  # a Header's seq, stamp.secs, stamp.nsecs: the first 12 bytes


class DecodePolicy:
    """The decode level of each (topic, type): `levels` maps topic names (with or without their
    leading '/') and message types to a level (a topic's entry wins over its type's), anything
    else gets `default`."""

    def __init__(self, levels: Optional[Mapping[str, str]] = None, default: str = "full"):
        levels = dict(levels or {})
        for name, level in list(levels.items()) + [("default", default)]:
            if level not in DECODE_LEVELS:
                raise ValueError(f"decode level for {name!r} must be one of {', '.join(DECODE_LEVELS)}, "
                                 f"got {level!r}")
        self.levels, self.default = levels, default
        self._cache: Dict[tuple, str] = {}

    def level(self, topic: str, msg_type: str) -> str:
        key = (topic, msg_type)
        level = self._cache.get(key)
        if level is None:
            level = (self.levels.get(topic) or self.levels.get(topic.lstrip("/"))
                     or self.levels.get(msg_type) or self.default)
            self._cache[key] = level
        return level


def stamp_from_bytes(raw: bytes) -> Optional[float]:
    """The header stamp (seconds) of a serialized message whose first field is a std_msgs/Header."""
    if len(raw) < _STAMP.size:
        return None
    _seq, secs, nsecs = _STAMP.unpack_from(raw)
    return float(secs) + float(nsecs) / 1e9  # as genpy's Time.to_sec
