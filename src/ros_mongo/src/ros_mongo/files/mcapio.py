"""MCAP files (what Foxglove opens) with ROS 1 messages, in the `ros_mongo.files.formats` shape.

Written as the MCAP `ros1` profile describes it: one schema per message type and definition
(encoding `ros1msg`, the full message definition text as in a bag's connection header), one
channel per topic info (publisher and source; message encoding `ros1`, metadata `callerid` and
`latching` "true"/"false", plus `md5sum`), each message with its exact serialized bytes and the
receive time as its log and publish time. The writer adds the summary section (schemas,
channels, statistics, chunk and message indexes), so viewers can seek.

Reading takes the same apart again, so database -> MCAP -> database -> MCAP keeps every message,
byte, time, type, md5sum, definition, callerid and latching flag. A file without the md5sum
metadata (written by another tool) gets the md5sum computed from its definition. A file without
a summary section (an unfinished recording) is read from the start up to the first record that
cannot be read; `McapReader.recovery` says what was recovered and skipped.

Uses the `mcap` package (PyPI), imported when an MCAP file is first read or written.
"""
from pathlib import Path
from typing import Dict, Iterator, Optional, Sequence, Tuple

import genpy

from ros_mongo.errors import BagError, UnknownTypeError
from ros_mongo.files.formats import (
    FileFormat,
    FileReader,
    FileWriter,
    RawMessage,
    Recovery,
    fingerprint_of,
    register_format,
)
from ros_mongo.messages.msgtypes import message_class

__all__ = ["McapReader", "McapWriter", "MCAP_MAGIC"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros1"
MESSAGE_ENCODING = "ros1"
SCHEMA_ENCODING = "ros1msg"
_COMPRESSIONS = {"none": "NONE", "lz4": "LZ4", "zstd": "ZSTD"}


def _mcap():
    try:
        import mcap  # noqa: F401 - only to say clearly when it is missing
    except ImportError:
        raise BagError("MCAP files need the Python package mcap (see requirements.txt)") from None
    import mcap.exceptions
    import mcap.reader
    import mcap.records
    import mcap.stream_reader
    import mcap.writer

    return mcap


def _stamp(nanoseconds: int) -> genpy.Time:
    return genpy.Time(nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000)


class McapReader(FileReader):
    """Messages of an MCAP file with ROS 1 channels (see the module docstring)."""

    def __init__(self, path, *, progress: bool = False):
        super().__init__(path, progress=progress)
        self.stream = None
        self.headers: Dict[int, Dict[str, str]] = {}     # channel id -> ROS 1 connection header
        self.classes: Dict[int, Optional[type]] = {}
        self.channel_counts: Dict[int, int] = {}
        self.topics_of: Dict[int, str] = {}
        self.foreign: Dict[int, str] = {}                 # channel id -> why it is no ROS 1 channel
        self.readable_end: Optional[int] = None          # set when there is no summary
        self._complete_scan = False

    def open(self) -> "McapReader":
        mcap = _mcap()
        try:
            self.handle = self.stream = open(self.path, "rb")
            reader = mcap.reader.make_reader(self.stream)
        except (OSError, mcap.exceptions.McapError) as err:
            self.close()
            raise BagError(f"cannot read MCAP file {self.path}: {err}") from None
        try:
            summary = reader.get_summary()
        except Exception:  # noqa: BLE001 - no readable footer: an unfinished file, read it linearly
            summary = None
        if summary is not None and summary.statistics is not None and (
                summary.chunk_indexes or not summary.statistics.message_count):
            statistics = summary.statistics
            self._connections(summary.schemas, summary.channels)
            self.channel_counts = dict(statistics.channel_message_counts)
            span = (statistics.message_start_time, statistics.message_end_time)
        else:
            span = self._scan()
        count = sum(n for i, n in self.channel_counts.items() if i in self.headers)
        connections = [(h["topic"], h["type"], h["md5sum"], h.get("callerid", ""))
                       for i, h in self.headers.items() if self.channel_counts.get(i)]
        start, end = (_stamp(span[0]).to_sec(), _stamp(span[1]).to_sec()) if count else (0.0, 0.0)
        self.fingerprint = fingerprint_of(start, end, count, connections)
        return self

    def count(self, topics: Optional[Sequence[str]] = None) -> int:
        self._check_channels(topics)
        return sum(n for i, n in self.channel_counts.items() if not topics or self.topics_of[i] in topics)

    def _check_channels(self, topics: Optional[Sequence[str]]) -> None:
        """BagError for selected channels with messages that hold no ROS 1 messages."""
        for channel_id, reason in self.foreign.items():
            if self.channel_counts.get(channel_id) and (not topics or self.topics_of[channel_id] in topics):
                raise BagError(f"cannot import MCAP file {self.path}: {reason}; choose the ROS 1 "
                               f"topics with --topics")

    def messages(self, topics: Optional[Sequence[str]] = None) -> Iterator[RawMessage]:
        mcap = _mcap()
        self._check_channels(topics)
        wanted = set(topics) if topics else None
        if self.readable_end is None:
            self.stream.seek(0)
            records = ((channel.id, message) for _schema, channel, message in
                       mcap.reader.make_reader(self.stream).iter_messages(topics=topics))
        else:
            records = ((message.channel_id, message) for message, _end in self._linear_messages())
        try:
            for channel_id, message in records:
                header = self.headers.get(channel_id)
                if header is None or (wanted is not None and header["topic"] not in wanted):
                    continue
                yield RawMessage(header["topic"], header["type"], header["md5sum"], message.data,
                                 _stamp(message.log_time), header, self.classes[channel_id])
        except (OSError, mcap.exceptions.McapError) as err:
            raise BagError(f"cannot read MCAP file {self.path}: {err}") from None

    # -- schemas and channels -------------------------------------------------------------------
    def _connections(self, schemas, channels) -> None:
        for channel in channels.values():
            self._add_channel(schemas, channel)

    def _add_channel(self, schemas, channel) -> None:
        schema = schemas.get(channel.schema_id)
        self.topics_of[channel.id] = channel.topic
        if (schema is None or schema.encoding != SCHEMA_ENCODING
                or channel.message_encoding != MESSAGE_ENCODING):
            found = f"{channel.message_encoding} / {schema.encoding if schema else 'no schema'}"
            self.foreign[channel.id] = (f"channel {channel.topic} holds {found}, not ROS 1 messages "
                                        f"({MESSAGE_ENCODING} / {SCHEMA_ENCODING})")
            return
        definition = schema.data.decode("utf-8", "replace")
        md5sum = channel.metadata.get("md5sum") or _md5_of(schema.name, definition, self.path)
        header = {"topic": channel.topic, "type": schema.name, "md5sum": md5sum,
                  "message_definition": definition,
                  "latching": "1" if channel.metadata.get("latching") in ("true", "1") else "0"}
        if "callerid" in channel.metadata:
            header["callerid"] = channel.metadata["callerid"]
        try:
            self.classes[channel.id] = message_class(schema.name, md5sum, definition)
        except UnknownTypeError:
            self.classes[channel.id] = None  # stored with its bytes, without decoded fields
        self.headers[channel.id] = header

    # -- files without a summary -----------------------------------------------------------------
    def _scan(self) -> Tuple[int, int]:
        """Counts, connections and time span read linearly; `recovery` when the file ends early."""
        start = end = None
        for message, _ in self._linear_messages():
            self.channel_counts[message.channel_id] = self.channel_counts.get(message.channel_id, 0) + 1
            start = message.log_time if start is None else min(start, message.log_time)
            end = message.log_time if end is None else max(end, message.log_time)
        if not self._complete_scan:
            self.recovery = Recovery(sum(self.channel_counts.values()),
                                     len({self.topics_of[i] for i in self.channel_counts}),
                                     self.path.stat().st_size - self.readable_end,
                                     "MCAP file without a summary")
        return (start or 0, end or 0)

    def _linear_messages(self) -> Iterator[Tuple[object, int]]:
        """(message, end offset of its record) up to the first record that cannot be read."""
        mcap = _mcap()
        records_module = mcap.records
        self.stream.seek(0)
        reader = mcap.stream_reader.StreamReader(self.stream, validate_crcs=True)
        schemas: Dict[int, object] = {}
        self._complete_scan = False
        self.readable_end = len(MCAP_MAGIC)
        records = reader.records
        while True:
            try:
                record = next(records)
            except StopIteration:
                self._complete_scan = True
                return
            except Exception:  # noqa: BLE001 - damaged or cut off here: what came before stays
                return
            position = self.stream.tell()
            if isinstance(record, records_module.Schema):
                schemas[record.id] = record
            elif isinstance(record, records_module.Channel):
                if record.id not in self.headers:
                    self._add_channel(schemas, record)
            elif isinstance(record, records_module.Message):
                yield record, position
            self.readable_end = position


def _md5_of(msg_type: str, definition: str, path: Path) -> str:
    import genpy.dynamic

    try:
        return genpy.dynamic.generate_dynamic(msg_type, definition)[msg_type]._md5sum
    except Exception as err:  # noqa: BLE001 - genmsg raises many kinds for bad text
        raise BagError(f"cannot import MCAP file {path}: the schema of {msg_type} does not parse as a "
                       f"ROS 1 message definition: {err}") from None


class McapWriter(FileWriter):
    """Writes stored messages to a new MCAP file (the module docstring says how)."""

    format_name = "mcap"
    compressions = tuple(_COMPRESSIONS)

    def _open(self, path: Path) -> None:
        mcap = _mcap()
        try:
            self.stream = open(path, "wb")
        except OSError as err:
            raise BagError(f"cannot write MCAP file {path}: {err.strerror or err}") from None
        compression = getattr(mcap.writer.CompressionType, _COMPRESSIONS[self.compression])
        self.writer = mcap.writer.Writer(self.stream, compression=compression)
        self.writer.start(profile=PROFILE, library="ros_mongo")
        self.schemas: Dict[Tuple[str, str], int] = {}
        self.channels: Dict[tuple, int] = {}
        self.sequence: Dict[int, int] = {}

    def _close(self) -> None:
        try:
            self.writer.finish()
        finally:
            self.stream.close()

    def write(self, info, stored) -> None:
        channel_id = self.channels.get(info.key)
        if channel_id is None:
            channel_id = self._channel(info)
        sequence = self.sequence[channel_id] = self.sequence[channel_id] + 1
        log_time = stored.receive_stamp.to_nsec()
        self.writer.add_message(channel_id, log_time=log_time, data=bytes(stored.raw),
                                publish_time=log_time, sequence=sequence)

    def _channel(self, info) -> int:
        schema_key = (info.msg_type, info.definition)
        schema_id = self.schemas.get(schema_key)
        if schema_id is None:
            schema_id = self.schemas[schema_key] = self.writer.register_schema(
                info.msg_type, SCHEMA_ENCODING, info.definition.encode("utf-8"))
        metadata = {"latching": "true" if info.latching else "false", "md5sum": info.md5sum}
        if info.callerid:
            metadata["callerid"] = info.callerid
        channel_id = self.channels[info.key] = self.writer.register_channel(
            info.topic, MESSAGE_ENCODING, schema_id, metadata)
        self.sequence[channel_id] = 0
        return channel_id


register_format(FileFormat("mcap", McapReader, McapWriter, (".mcap",), MCAP_MAGIC,
                           McapWriter.compressions))
