"""A local append-only spool file for records the database could not take yet.

Each entry is one frame: magic b"RMS1", header length, payload length, CRC-32 (all uint32 little
endian), a JSON header, then the payload (the exact serialized message bytes). How far the file has
been drained into the database is kept in `<path>.offset` (replaced atomically); once everything is
drained the file is emptied. A torn last frame (the process was killed mid-write) is cut off when the
spool is opened again. Entries are either topic infos or message records; records keep their ids, so
draining an entry twice (killed between insert and offset update) still stores it once.

Bounds: `max_bytes` (the file's size, default 4 GiB) and `min_free_bytes` (free space left on the
file system, default 1 GiB, like `rosbag record --min-space`): an append that would cross either
raises SpoolFull and writes nothing. The same framed format holds the recorder's quarantine file
(ros_mongo.recording.quarantine).
"""
import fcntl
import os
import struct
import threading
import zlib
from dataclasses import fields
from pathlib import Path
from typing import Dict, List, Tuple, Union

import orjson

from ros_mongo.errors import SpoolError
from ros_mongo.recording.limits import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES
from ros_mongo.records import MessageRecord, TopicInfo
from ros_mongo.storage.chunks import ChunkRecord, message_count

__all__ = ["Spool", "SpoolFull", "DEFAULT_MAX_BYTES", "DEFAULT_MIN_FREE_BYTES", "read_entries", "frames"]


MAGIC = b"RMS1"
_FRAME = struct.Struct("<4sIII")
_EXCLUSIVE_NONBLOCKING = fcntl.LOCK_EX + fcntl.LOCK_NB  # (distinct bits; "|" trips vermin's 3.10 check)
Entry = Union[TopicInfo, MessageRecord, ChunkRecord]


class SpoolFull(SpoolError):
    """An append would cross the spool's size limit or its minimum free disk space."""


class Spool:
    """Append entries, read them back in order from the drained offset, commit what was drained.

    Args:
        path: the spool file (its directory is created).
        fsync: also fsync after each append (survives power loss, not only a killed process).
        max_bytes: the file's size limit (bytes not yet drained count; drained ones are freed
            when the spool empties).
        min_free_bytes: free space an append must leave on the file system.
    """

    def __init__(self, path: Union[str, Path], *, fsync: bool = False, max_bytes: int = DEFAULT_MAX_BYTES,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES):
        if max_bytes < 1 or min_free_bytes < 0:
            raise ValueError(f"spool max_bytes must be positive and min_free_bytes not negative, got "
                             f"{max_bytes!r} and {min_free_bytes!r}")
        self.path = Path(path)
        self.offset_path = Path(str(self.path) + ".offset")
        self.fsync = fsync
        self.max_bytes, self.min_free_bytes = int(max_bytes), int(min_free_bytes)
        self._lock = threading.Lock()
        self._file = None
        self._end = 0
        self._offset = 0
        self.pending_records = 0
        self.generation = 0  # counts the times the file was emptied after a full drain

    def open(self) -> "Spool":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "a+b")
            fcntl.flock(self._file.fileno(), _EXCLUSIVE_NONBLOCKING)
        except BlockingIOError:
            self._file.close()
            raise SpoolError(f"spool {self.path} is in use by another recorder") from None
        except OSError as err:
            raise SpoolError(f"cannot open spool {self.path}: {err}") from err
        self._offset = self._read_offset()
        self._end, self.pending_records = self._scan_valid_end()
        size = os.fstat(self._file.fileno()).st_size
        if size > self._end:  # a torn frame from a killed process
            self._file.truncate(self._end)
        return self

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    @property
    def pending(self) -> bool:
        return self._end > self._offset

    @property
    def pending_bytes(self) -> int:
        return self._end - self._offset

    def append(self, entries: List[Entry]) -> None:
        """Write entries at the end (flushed to the OS before returning)."""
        self.append_frames(*frames(entries))

    def append_frames(self, data: bytes, records: int) -> None:
        """Write entries framed by `frames` (holding `records` messages) at the end."""
        with self._lock:
            if self._end + len(data) > self.max_bytes:
                raise SpoolFull(f"spool {self.path} is full: {self._end + len(data)} bytes would exceed "
                                f"its limit of {self.max_bytes}")
            try:
                stats = os.statvfs(self.path.parent)
            except OSError as err:
                raise SpoolError(f"cannot check the free space for spool {self.path}: {err}") from err
            if stats.f_bavail * stats.f_frsize - len(data) < self.min_free_bytes:
                raise SpoolFull(f"spool {self.path}: appending {len(data)} bytes would leave less than "
                                f"the minimum free space of {self.min_free_bytes} bytes")
            try:
                self._file.seek(0, os.SEEK_END)
                self._file.write(data)
                self._file.flush()
                if self.fsync:
                    os.fsync(self._file.fileno())
            except OSError as err:
                raise SpoolError(f"cannot write spool {self.path}: {err}") from err
            self._end += len(data)
            self.pending_records += records

    def read(self, max_entries: int = 500, max_bytes: int = 16 * 1024 * 1024) -> Tuple[List[Entry], int]:
        """Entries from the drained offset on, and the offset after them (for commit)."""
        with self._lock:
            offset, end = self._offset, self._end
            entries, size = [], 0
            with open(self.path, "rb") as reader:
                reader.seek(offset)
                while offset < end and len(entries) < max_entries and size < max_bytes:
                    entry, length = _read_frame(reader)
                    if entry is None:
                        raise SpoolError(f"spool {self.path} is corrupt at byte {offset}")
                    entries.append(entry)
                    offset += length
                    size += length
            return entries, offset

    def commit(self, offset: int, records: int) -> None:
        """Mark everything before `offset` (holding `records` messages) as stored."""
        with self._lock:
            self._offset = offset
            self.pending_records = max(0, self.pending_records - records)
            if self._offset >= self._end:  # all drained: start over with an empty file
                self._offset = 0
                self._write_offset()  # first: killed before the truncation only re-drains (ids dedupe)
                self._file.truncate(0)
                self._end = self.pending_records = 0
                self.generation += 1
            else:
                self._write_offset()

    def pending_topics(self) -> Dict[str, int]:
        """Messages not yet drained, per topic (read from the frames' headers)."""
        counts: Dict[str, int] = {}
        with self._lock:
            offset, end = self._offset, self._end
            with open(self.path, "rb") as reader:
                reader.seek(offset)
                while offset < end:
                    head = reader.read(_FRAME.size)
                    if len(head) < _FRAME.size:
                        break
                    _magic, header_len, payload_len, _crc = _FRAME.unpack(head)
                    header = orjson.loads(reader.read(header_len))
                    reader.seek(payload_len, os.SEEK_CUR)
                    if header.get("kind") == "message":
                        counts[header["topic"]] = counts.get(header["topic"], 0) + 1
                    elif header.get("kind") == "chunk":
                        topic = header["records"][0]["topic"]
                        counts[topic] = counts.get(topic, 0) + len(header["records"])
                    offset += _FRAME.size + header_len + payload_len
        return counts

    def remove(self) -> None:
        """Close and delete the spool file and its offset file (what it held is given up)."""
        self.close()
        for path in (self.path, self.offset_path):
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError as err:
                raise SpoolError(f"cannot delete {path}: {err}") from err

    @property
    def size(self) -> int:
        """Bytes the file holds (drained ones included until it is emptied)."""
        return self._end

    def _read_offset(self) -> int:
        try:
            return int(self.offset_path.read_text().strip() or 0)
        except FileNotFoundError:
            return 0
        except (OSError, ValueError) as err:
            raise SpoolError(f"cannot read spool offset {self.offset_path}: {err}") from err

    def _write_offset(self) -> None:
        temporary = Path(str(self.offset_path) + ".tmp")
        try:
            temporary.write_text(str(self._offset))
            os.replace(temporary, self.offset_path)
        except OSError as err:
            raise SpoolError(f"cannot write spool offset {self.offset_path}: {err}") from err

    def _scan_valid_end(self) -> Tuple[int, int]:
        size = os.fstat(self._file.fileno()).st_size
        if self._offset > size:  # emptied after the offset was written: drain all (ids dedupe)
            self._offset = 0
        offset, records = self._offset, 0
        with open(self.path, "rb") as reader:
            reader.seek(offset)
            while offset < size:
                entry, length = _read_frame(reader)
                if entry is None:
                    break
                offset += length
                records += message_count(entry)
        return offset, records


def read_entries(path: Union[str, Path]) -> List[Entry]:
    """Every entry of a spool-format file (spool or quarantine), from its beginning, without
    locking it; a torn last frame ends the list, a corrupt one in the middle raises SpoolError."""
    entries: List[Entry] = []
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as reader:
            offset = 0
            while offset < size:
                entry, length = _read_frame(reader)
                if entry is None:
                    if reader.tell() < size:
                        raise SpoolError(f"{path} is corrupt at byte {offset}")
                    break
                entries.append(entry)
                offset += length
    except OSError as err:
        raise SpoolError(f"cannot read {path}: {err}") from err
    return entries


_TOPIC_FIELDS = tuple(f.name for f in fields(TopicInfo))
_RECORD_FIELDS = tuple(f.name for f in fields(MessageRecord) if f.name != "raw")


def frames(entries: List[Entry]) -> Tuple[bytes, int]:
    """The frames of `entries` as one bytes object, and how many messages they hold."""
    parts, records = [], 0
    for entry in entries:
        parts.append(_frame(entry))
        records += message_count(entry)
    return b"".join(parts), records


def _frame(entry: Entry) -> bytes:
    if isinstance(entry, TopicInfo):
        header = {"kind": "topic", **{name: getattr(entry, name) for name in _TOPIC_FIELDS}}
        payload = b""
    elif isinstance(entry, ChunkRecord):  # its records' fields, their bytes one after another
        header = {"kind": "chunk", "records": [{name: getattr(record, name) for name in _RECORD_FIELDS}
                                               for record in entry.records],
                  "sizes": [len(record.raw) for record in entry.records]}
        payload = entry.raw
    else:  # the fields as they are (not deep-copied as dataclasses.asdict would)
        header = {"kind": "message", **{name: getattr(entry, name) for name in _RECORD_FIELDS}}
        payload = entry.raw
    try:
        header_bytes = orjson.dumps(header)
    except TypeError as err:
        raise SpoolError(f"cannot write a spool frame for {header.get('topic')}: {err}") from err
    crc = zlib.crc32(payload, zlib.crc32(header_bytes))
    return _FRAME.pack(MAGIC, len(header_bytes), len(payload), crc) + header_bytes + payload


def _read_frame(reader) -> Tuple[Union[Entry, None], int]:
    head = reader.read(_FRAME.size)
    if len(head) < _FRAME.size:
        return None, 0
    magic, header_len, payload_len, crc = _FRAME.unpack(head)
    if magic != MAGIC:
        return None, 0
    header_bytes = reader.read(header_len)
    payload = reader.read(payload_len)
    if len(header_bytes) < header_len or len(payload) < payload_len \
            or zlib.crc32(payload, zlib.crc32(header_bytes)) != crc:
        return None, 0
    header = orjson.loads(header_bytes)
    kind = header.pop("kind")
    if kind == "chunk":
        records, at = [], 0
        for fields_, size in zip(header["records"], header["sizes"]):
            records.append(MessageRecord(raw=payload[at:at + size], **fields_))
            at += size
        entry: Entry = ChunkRecord(records)
    else:
        entry = TopicInfo(**header) if kind == "topic" else MessageRecord(raw=payload, **header)
    return entry, _FRAME.size + header_len + payload_len
