"""The original mongodb_api's face, in one place (pure Python: no ROS master needed).

The original package (a ROS 1 MongoDB data logger) read global parameters from its
config/server_config.yaml and stored flat documents in `test_database.posts`:

    {session_id, author, time (receive time, float s), tags: [image | joint_states | lidar | odom],
     ...the sensor's fields: image height, width, data; joint_states joint_names, position, velocity,
     effort; lidar angle_min, angle_max, angle_increment, time_increment, range_min, range_max,
     ranges; odom position [x, y, z], velocity [linear.x, linear.y, angular.z]}

This module maps
- its global parameters onto today's private ones (`legacy_overrides`, one deprecation warning
  each; the private parameter wins when both are given),
- its documents onto today's message records (`original_message`, `migrate_documents`: what the
  original never stored is reported per field, never invented),
- today's stored messages back into its flat form (`original_document`, for SensorData.srv).

A private parameter counts as given when it differs from its default: the launch files load the
defaults from config/*.yaml, so a private value equal to the default cannot be told apart from
one that was not set.
"""
import base64
import hashlib
from collections import Counter
from dataclasses import dataclass, field
from io import BytesIO
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Tuple

import genpy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, JointState, LaserScan

from ros_mongo.errors import StoreError
from ros_mongo.records import MessageRecord, StoredMessage, TopicInfo, make_record, new_message_id, split_time

__all__ = ["LEGACY_DATABASE", "LEGACY_COLLECTION", "LEGACY_PARAMS", "DEFAULT_BAG_NAME", "WRITE_BAG",
           "WRITE_DATABASE", "ORIGINAL_TAG_TOPICS", "legacy_db_url", "legacy_overrides", "legacy_config",
           "LegacyDocumentError", "original_message", "original_document", "MigrationReport",
           "migrated_record", "migrate_documents"]

LEGACY_DATABASE = "test_database"
LEGACY_COLLECTION = "posts"
DEFAULT_SERVER_IP = "localhost"
DEFAULT_PORT = 27017
DEFAULT_BAG_NAME = "mongodb_to_bag.bag"
WRITE_BAG, WRITE_DATABASE = "write_bag", "write_database"

#: the original's tag -> the topic its server subscribed for it
ORIGINAL_TAG_TOPICS = {"image": "/camera/rgb/image_raw", "joint_states": "/joint_states",
                       "lidar": "/scan", "odom": "/odom"}
#: the original's log_<sensor> switches -> the topic each one turned on or off
LOG_SWITCHES = {"log_image": "/camera/rgb/image_raw", "log_joint": "/joint_states",
                "log_lidar": "/scan", "log_odom": "/odom"}

#: node -> the original global parameter -> the private parameter that replaces it
LEGACY_PARAMS: Dict[str, Dict[str, str]] = {
    "recorder": {"server_ip": "db_url", "port": "db_url", "author": "author",
                 "session_id": "session_id", **{name: "topics" for name in LOG_SWITCHES}},
    "retriever": {"server_ip": "db_url", "port": "db_url", "data_rate": "fixed_rate"},
    "converter": {"server_ip": "db_url", "port": "db_url", "bag_name": "bag",
                  "where_to_write": "direction", "session_id": "session_id"},
}


def legacy_db_url(server_ip: Any = None, port: Any = None) -> str:
    """The database URL of the original's `server_ip` and `port`: its MongoDB, its database."""
    host = str(server_ip) if server_ip not in (None, "") else DEFAULT_SERVER_IP
    return f"mongodb://{host}:{int(port) if port not in (None, '') else DEFAULT_PORT}/{LEGACY_DATABASE}"


def legacy_overrides(node: str, global_params: Mapping[str, Any], private_params: Mapping[str, Any],
                     defaults: Mapping[str, Any]) -> Tuple[Dict[str, Any], List[str]]:
    """The private parameter values the original global parameters give `node` ("recorder",
    "retriever" or "converter"), and one deprecation warning line per global parameter used.

    `global_params` holds the original parameters that are set, `private_params` the node's own,
    `defaults` the private parameters' defaults. A private parameter given (not its default) wins.
    """
    names = LEGACY_PARAMS[node]
    used = {name: value for name, value in global_params.items() if name in names}
    overrides: Dict[str, Any] = {}
    warnings: List[str] = []

    def given(private: str) -> bool:
        return private in private_params and private_params[private] != defaults.get(private)

    def value_of(name: str, private: str, value: Any) -> Any:
        if private == "db_url":
            return legacy_db_url(used.get("server_ip"), used.get("port"))
        if private == "topics":
            current = list(private_params.get("topics", defaults.get("topics", [])))
            off = {LOG_SWITCHES[n] for n, on in used.items() if n in LOG_SWITCHES and not _truth(on)}
            return [topic for topic in current if topic not in off]
        if private == "fixed_rate":
            return float(value)
        if private == "direction":
            return {WRITE_BAG: "export", WRITE_DATABASE: "import"}.get(str(value), str(value))
        return str(value)

    for name, value in sorted(used.items()):
        private = names[name]
        if given(private):
            warnings.append(f"deprecated global parameter '{name}' (mongodb_api) ignored: the private "
                            f"~{private} is set and wins")
            continue
        new_value = value_of(name, private, value)
        overrides[private] = new_value
        warnings.append(f"deprecated global parameter '{name}' (mongodb_api): use ~{private} instead "
                        f"(now ~{private}={new_value!r})")
    return overrides, warnings


def legacy_config(config_cls: type, node: str, private_params: Mapping[str, Any],
                  get_global: Callable[[str], Any], warn: Callable[[str], None]):
    """`config_cls` (a NodeConfig) from the node's private parameters and the original global
    ones (`get_global(name)` raises KeyError when unset, as rospy.get_param does); each global
    one used is warned about once through `warn`."""
    global_params = {}
    for name in LEGACY_PARAMS[node]:
        try:
            global_params[name] = get_global(name)
        except KeyError:
            continue
    overrides, warnings = legacy_overrides(node, global_params, private_params, config_cls.defaults())
    for line in warnings:
        warn(line)
    return config_cls.from_mapping({**private_params, **overrides})


def _truth(value: Any) -> bool:
    if isinstance(value, str):
        return value.strip().lower() not in ("false", "0", "no", "off", "")
    return bool(value)


# -- the original's documents ------------------------------------------------------------------

class LegacyDocumentError(StoreError, ValueError):
    """An original document that cannot become a message (no time, unknown tag, ...)."""


@dataclass(frozen=True)
class _Slot:
    """One original field: its key, the message attribute it fills, and how."""

    key: str
    path: str                              # dotted message attribute
    index: Optional[int] = None            # element of a list-valued original field
    convert: Callable[[Any], Any] = lambda v: v


def _bytes(value: Any) -> bytes:
    if isinstance(value, (bytes, bytearray)):
        return bytes(value)
    if isinstance(value, str):  # Python 2 stored str: one byte per character
        return value.encode("latin-1")
    return bytes(int(v) for v in value)


def _floats(value: Any) -> List[float]:
    return [float(v) for v in value]


def _strings(value: Any) -> List[str]:
    return [str(v) for v in value]


_SPECS: Dict[str, Tuple[type, List[_Slot], List[str]]] = {
    # tag: (message class, the original's fields, what the original never stored)
    "image": (Image, [_Slot("height", "height", convert=int), _Slot("width", "width", convert=int),
                      _Slot("data", "data", convert=_bytes)],
              ["header.stamp", "header.frame_id", "encoding", "is_bigendian", "step"]),
    "joint_states": (JointState, [_Slot("joint_names", "name", convert=_strings),
                                  _Slot("position", "position", convert=_floats),
                                  _Slot("velocity", "velocity", convert=_floats),
                                  _Slot("effort", "effort", convert=_floats)],
                     ["header.stamp", "header.frame_id"]),
    "lidar": (LaserScan, [_Slot(k, k, convert=float) for k in
                          ("angle_min", "angle_max", "angle_increment", "time_increment", "range_min",
                           "range_max")] + [_Slot("ranges", "ranges", convert=_floats)],
              ["header.stamp", "header.frame_id", "scan_time", "intensities"]),
    "odom": (Odometry, [_Slot("position", "pose.pose.position.x", 0, float),
                        _Slot("position", "pose.pose.position.y", 1, float),
                        _Slot("position", "pose.pose.position.z", 2, float),
                        _Slot("velocity", "twist.twist.linear.x", 0, float),
                        _Slot("velocity", "twist.twist.linear.y", 1, float),
                        _Slot("velocity", "twist.twist.angular.z", 2, float)],
             ["header.stamp", "header.frame_id", "child_frame_id", "pose.pose.orientation",
              "pose.covariance", "twist.twist.linear.z", "twist.twist.angular.x", "twist.twist.angular.y",
              "twist.covariance"]),
}
_TAG_ALIASES = {"joint_state": "joint_states"}  # the original retriever's spelling
#: what no original document holds, whatever its tag
NEVER_STORED = ["exact serialized bytes (re-serialized from the stored fields)",
                "md5sum and message definition (today's sensor_msgs/nav_msgs types assumed)",
                "callerid (the publisher)", "robot_id"]


def _tag_of(doc: Mapping[str, Any]) -> str:
    tags = doc.get("tags")
    if not isinstance(tags, (list, tuple)) or not tags:
        raise LegacyDocumentError("no tags")
    tag = _TAG_ALIASES.get(str(tags[0]), str(tags[0]))
    if tag not in _SPECS:
        raise LegacyDocumentError(f"unknown tag {tags[0]!r}")
    return tag


def original_message(doc: Mapping[str, Any]) -> Tuple[str, str, genpy.Message, List[str], List[str]]:
    """(tag, topic, message, reconstructed fields, missing fields) of an original document; the
    fields are the message's (e.g. "pose.pose.position.x"). LegacyDocumentError if it has no
    usable tag."""
    tag = _tag_of(doc)
    cls, slots, never = _SPECS[tag]
    msg = cls()
    reconstructed, missing = [], list(never)
    for slot in slots:
        value = doc.get(slot.key)
        try:
            if slot.index is not None:
                value = value[slot.index]
            if value is None:
                raise TypeError("null")
            value = slot.convert(value)
        except (TypeError, ValueError, IndexError, KeyError, OverflowError):
            missing.append(slot.path)
            continue
        _set(msg, slot.path, value)
        reconstructed.append(slot.path)
    return tag, ORIGINAL_TAG_TOPICS[tag], msg, reconstructed, missing


def _set(msg: Any, path: str, value: Any) -> None:
    *parents, last = path.split(".")
    for name in parents:
        msg = getattr(msg, name)
    setattr(msg, last, value)


def _get(msg: Any, path: str) -> Any:
    for name in path.split("."):
        msg = getattr(msg, name)
    return msg


def original_document(stored: StoredMessage) -> Dict[str, Any]:
    """A stored message in the original's flat form (JSON-ready: image data as base64 text).
    Other types than the original four: topic, type and the decoded fields under "msg"."""
    doc: Dict[str, Any] = {"session_id": stored.session_id, "author": stored.author,
                           "time": stored.receive_time, "tags": list(stored.tags)}
    tag = next((t for t, spec in _SPECS.items() if spec[0]._type == stored.msg_type
                and spec[0]._md5sum == stored.md5sum), None)
    if tag is None:
        doc.update(topic=stored.topic, type=stored.msg_type, msg=stored.fields)
        return doc
    msg = stored.message()
    for slot in _SPECS[tag][1]:
        value = _get(msg, slot.path)
        if slot.key == "data":
            doc["data"] = base64.b64encode(bytes(value)).decode("ascii")
        elif slot.index is not None:
            doc.setdefault(slot.key, [None] * 3)[slot.index] = value
        else:
            doc[slot.key] = list(value) if isinstance(value, (list, tuple)) else value
    return doc


# -- migration -----------------------------------------------------------------------------

@dataclass
class MigrationReport:
    """What a migration did: documents read, messages newly stored or already there, documents
    skipped (with why), and per tag how often each field was reconstructed or missing."""

    read: int = 0
    stored: int = 0
    already_present: int = 0
    skipped: Counter = field(default_factory=Counter)
    per_tag: Dict[str, int] = field(default_factory=Counter)
    reconstructed: Dict[str, Counter] = field(default_factory=dict)
    missing: Dict[str, Counter] = field(default_factory=dict)

    def lines(self) -> List[str]:
        """The report, as lines for a terminal."""
        out = [f"read {self.read} original documents: {self.stored} messages stored, "
               f"{self.already_present} already present (not rewritten), "
               f"{sum(self.skipped.values())} skipped"]
        out += [f"  skipped {count}: {reason}" for reason, count in sorted(self.skipped.items())]
        for tag in sorted(self.per_tag):
            out.append(f"{tag} ({ORIGINAL_TAG_TOPICS[tag]}, {_SPECS[tag][0]._type}): "
                       f"{self.per_tag[tag]} documents")
            out += [f"  reconstructed {name}: {n}" for name, n in sorted(self.reconstructed[tag].items())]
            out += [f"  missing {name}: {n} (the original did not store it; left at its default)"
                    for name, n in sorted(self.missing[tag].items())]
        if self.per_tag:
            out.append("kept as stored: time -> receive_time, session_id, author, tags")
            out += [f"never stored by the original, not invented: {what}" for what in NEVER_STORED]
        return out


def migrated_record(doc: Mapping[str, Any], *, robot_id: Optional[str] = None,
                    max_array_len: Optional[int] = None) -> Tuple[str, MessageRecord, List[str], List[str]]:
    """(tag, record, reconstructed, missing) for an original document; the record's id depends
    only on the document's `_id` and time, so a second migration finds it stored already."""
    tag, topic, msg, reconstructed, missing = original_message(doc)
    try:
        stamp = split_time(float(doc["time"]))
    except (KeyError, TypeError, ValueError):
        raise LegacyDocumentError("no time") from None
    token = hashlib.sha1(str(doc.get("_id")).encode("utf-8")).hexdigest()[:24]
    session = doc.get("session_id")
    options = {} if max_array_len is None else {"max_array_len": max_array_len}
    buffer = BytesIO()
    msg.serialize(buffer)
    record = make_record(topic, type(msg), buffer.getvalue(), receive=stamp,
                         tags=[str(t) for t in doc.get("tags") or []],
                         session_id=None if session is None else str(session), robot_id=robot_id,
                         record_id=new_message_id(stamp.secs, stamp.nsecs, robot_id, token=token),
                         message=msg, author=None if doc.get("author") is None else str(doc["author"]),
                         **options)
    record.header_stamp = None  # the original stored no header: its stamp is unknown, not 0
    return tag, record, reconstructed, missing


def migrate_documents(docs: Iterable[Mapping[str, Any]], store, *, robot_id: Optional[str] = None,
                      batch: int = 500,
                      on_progress: Callable[[int], None] = lambda n: None) -> MigrationReport:
    """Store the original documents `docs` in `store` in today's layout (ids already stored are
    left as they are), reporting per field what was reconstructed and what is missing."""
    report = MigrationReport()
    pending: List[MessageRecord] = []
    topics_put = set()

    def flush() -> None:
        stored = store.insert_records(pending)
        report.stored += stored
        report.already_present += len(pending) - stored
        on_progress(len(pending))
        pending.clear()

    for doc in docs:
        report.read += 1
        try:
            tag, record, reconstructed, missing = migrated_record(doc, robot_id=robot_id,
                                                                  max_array_len=store.max_array_len)
        except LegacyDocumentError as err:
            report.skipped[str(err)] += 1
            on_progress(1)
            continue
        if tag not in topics_put:
            store.put_topic(TopicInfo.of_class(record.topic, _SPECS[tag][0], robot_id=robot_id or ""))
            topics_put.add(tag)
        report.per_tag[tag] += 1
        report.reconstructed.setdefault(tag, Counter()).update(reconstructed)
        report.missing.setdefault(tag, Counter()).update(missing)
        pending.append(record)
        if len(pending) >= batch:
            flush()
    if pending:
        flush()
    return report

