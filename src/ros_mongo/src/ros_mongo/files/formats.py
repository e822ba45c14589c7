"""Log-file formats (ROS 1 bags, MCAP) behind one reader / writer shape and a registry by name.

A reader yields `RawMessage`s (topic, type, md5sum, exact bytes, log time, the ROS 1 connection
header); a writer takes a stored message with its `TopicInfo`. Both follow one shape:
`__init__(path, ...)` only checks arguments, `open()` / `close()` do the I/O, and a context manager
wraps them. A writer refuses to overwrite an existing file (unless told to), writes to
`<path>.partial` and renames it only once the file is complete, so an interrupted export never
leaves a half-written file under the requested name.

Formats register themselves with `register_format` (as `ros_mongo.files.bagfile` and
`ros_mongo.files.mcapio` do when imported); `format_of_file` recognises a file by its first bytes and
`format_for_path` picks the format of a file to write by name or suffix.
"""
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple, Union

import genpy

from ros_mongo.errors import BagError

__all__ = ["RawMessage", "Recovery", "FileFormat", "FileWriter", "register_format", "format_named",
           "format_of_file", "format_for_path", "format_names", "FileReader", "fingerprint_of", "iter_file"]

PathLike = Union[str, Path]


class RawMessage(NamedTuple):
    """One message of a log file, exactly as stored there."""

    topic: str
    msg_type: str
    md5sum: str
    data: bytes
    stamp: genpy.Time            # the log (receive) time
    header: Dict[str, str]       # ROS 1 connection header: type, md5sum, message_definition, ...
    pytype: Optional[type]       # a genpy class for decoding the fields, None when unusable


@dataclass
class Recovery:
    """What reading a damaged or unfinished file (no index) recovered and what it had to skip."""

    messages: int
    topics: int
    skipped_bytes: int
    reason: str

    def describe(self) -> str:
        return (f"{self.reason}: recovered {self.messages} messages on {self.topics} topics, "
                f"skipped {self.skipped_bytes} unreadable bytes")


@dataclass(frozen=True)
class FileFormat:
    """A registered format: its reader and writer classes, file suffixes, leading magic bytes and
    the compressions its writer offers (the first is the default)."""

    name: str
    reader: Callable[..., object]
    writer: Callable[..., object]
    suffixes: Tuple[str, ...]
    magic: bytes
    compressions: Tuple[str, ...]


_FORMATS: Dict[str, FileFormat] = {}


def register_format(file_format: FileFormat) -> None:
    """Make `file_format` available by its name, suffixes and magic bytes."""
    _FORMATS[file_format.name] = file_format


def format_names() -> List[str]:
    return sorted(_FORMATS)


def format_named(name: str) -> FileFormat:
    try:
        return _FORMATS[name]
    except KeyError:
        raise BagError(f"unknown file format {name!r}; known: {', '.join(format_names())}") from None


def format_of_file(path: PathLike) -> FileFormat:
    """The format of an existing file, recognised by its first bytes (BagError if none fits)."""
    try:
        with open(path, "rb") as stream:
            head = stream.read(max((len(f.magic) for f in _FORMATS.values()), default=0))
    except OSError as err:
        raise BagError(f"cannot read bag {path}: {err.strerror or err}") from None
    for file_format in _FORMATS.values():
        if head.startswith(file_format.magic):
            return file_format
    raise BagError(f"cannot read bag {path}: neither a ROS bag nor an MCAP file (it starts with "
                   f"{head[:13]!r})")


def format_for_path(path: PathLike, name: Optional[str] = None) -> FileFormat:
    """The format to write `path` in: `name` if given, else by suffix (.mcap), else a bag."""
    if name:
        return format_named(name)
    suffix = Path(path).suffix.lower()
    for file_format in _FORMATS.values():
        if suffix in file_format.suffixes:
            return file_format
    return format_named("bag")


class FileWriter:
    """Base of the format writers: refuses to overwrite, writes `<path>.partial`, renames it on a
    successful `close()`, deletes it on `abort()` (or when the `with` block raised)."""

    format_name = ""
    compressions: Sequence[str] = ("none",)

    def __init__(self, path: PathLike, *, overwrite: bool = False, compression: str = "none"):
        self.path = Path(path)
        self.partial = Path(str(self.path) + ".partial")
        self.overwrite = overwrite
        if compression not in self.compressions:
            raise BagError(f"{self.format_name} compression must be one of {list(self.compressions)}, "
                           f"got {compression!r}")
        self.compression = compression
        self.is_open = False

    def open(self) -> "FileWriter":
        if self.path.exists() and not self.overwrite:
            raise BagError(f"bag {self.path} exists; choose another name or overwrite it explicitly")
        self._open(self.partial)
        self.is_open = True
        return self

    def close(self) -> None:
        """Finish the file and give it its name."""
        if self.is_open:
            self.is_open = False
            self._close()
            os.replace(self.partial, self.path)

    def abort(self) -> None:
        """Drop what was written so far."""
        if self.is_open:
            self.is_open = False
            try:
                self._close()
            finally:
                self.partial.unlink(missing_ok=True)

    def __enter__(self) -> "FileWriter":
        return self.open()

    def __exit__(self, kind, _value, _traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    # -- for the formats -----------------------------------------------------------------------
    def _open(self, path: Path) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def write(self, info, stored) -> None:
        """Write the stored message `stored` on the connection / channel of `info` (TopicInfo)."""
        raise NotImplementedError


class FileReader:
    """Base of the format readers: `open()` / `close()` and a context manager; after `open()`,
    `fingerprint`, `count(topics)`, `messages(topics)` and `recovery` (None for an intact file).
    `handle` is what `open()` opened and `close()` closes."""

    def __init__(self, path: PathLike, *, progress: bool = False):
        self.path = Path(path)
        self.progress = progress
        self.handle = None
        self.fingerprint = ""
        self.recovery: Optional[Recovery] = None

    def open(self) -> "FileReader":
        raise NotImplementedError

    def close(self) -> None:
        if self.handle is not None:
            self.handle.close()
            self.handle = None

    def count(self, topics: Optional[Sequence[str]] = None) -> int:
        raise NotImplementedError

    def messages(self, topics: Optional[Sequence[str]] = None) -> Iterator[RawMessage]:
        raise NotImplementedError

    def __enter__(self) -> "FileReader":
        try:
            return self.open()
        except BaseException:
            self.close()  # what open() had opened before it failed
            raise

    def __exit__(self, *_exc) -> None:
        self.close()


def iter_file(path: PathLike) -> Iterator[Tuple[str, bytes, genpy.Time, Dict[str, str]]]:
    """(topic, raw bytes, log time, ROS 1 connection header) of every message of a bag or MCAP
    file, in the reader's order (for checks and tests)."""
    with format_of_file(path).reader(path) as reader:
        for message in reader.messages():
            yield message.topic, bytes(message.data), message.stamp, message.header


def fingerprint_of(start: float, end: float, count: int,
                   connections: Sequence[Tuple[str, str, str, str]]) -> str:
    """What identifies a log's content without reading it all: its time span, message count and
    connections (topic, type, md5sum, callerid). The same for a bag and an MCAP file of the same
    messages and connections, so importing both stores nothing twice. `start` and `end` are in
    seconds (`genpy.Time.to_sec()`)."""
    key = f"{start!r}\n{end!r}\n{count}\n{sorted(connections)!r}"
    return hashlib.sha1(key.encode()).hexdigest()
