"""ROS 1 bags (rosbag's own reader and writer) in the `ros_mongo.files.formats` shape.

Reading an unindexed bag (left by a `rosbag record` that crashed or was killed: a `.bag.active`
file, or a bag whose index was cut off) rebuilds the index in memory the way `rosbag reindex`
does, chunk by chunk, without touching the file (`rosbag reindex` truncates a copy after the last
readable chunk): every message of a complete chunk is recovered, an unfinished chunk at the end is
skipped, and `BagReader.recovery` says how many messages on how many topics were recovered and
how many bytes were skipped. The index is the one `rosbag reindex` would write, so the recovered
bag has the same fingerprint as the bag `rosbag reindex` makes of it (importing both stores
nothing twice).
"""
from pathlib import Path
from typing import Dict, Iterator, Optional, Sequence, Tuple

from ros_mongo.errors import BagError
from ros_mongo.files.formats import (
    FileFormat,
    FileReader,
    FileWriter,
    RawMessage,
    Recovery,
    fingerprint_of,
    register_format,
)

__all__ = ["BagReader", "BagWriter", "BAG_MAGIC"]

BAG_MAGIC = b"#ROSBAG V"


def _text(header: Dict, key: str) -> str:
    value = header.get(key, b"")
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


class BagReader(FileReader):
    """Messages of a ROS 1 bag, indexed or not (see the module docstring)."""

    def open(self) -> "BagReader":
        import rosbag

        try:
            self.handle = self.bag = rosbag.Bag(str(self.path), "r")
        except rosbag.ROSBagUnindexedException:
            self._open_unindexed()
        except (rosbag.ROSBagException, OSError, ValueError) as err:
            raise BagError(f"cannot read bag {self.path}: {err}") from None
        self.fingerprint = self._fingerprint()
        return self

    def count(self, topics: Optional[Sequence[str]] = None) -> int:
        return self.bag.get_message_count(topic_filters=list(topics) if topics else None)

    def messages(self, topics: Optional[Sequence[str]] = None) -> Iterator[RawMessage]:
        import rosbag

        try:
            for topic, raw, stamp, header in self.bag.read_messages(topics=topics, raw=True,
                                                                    return_connection_header=True):
                msg_type, data, md5sum, _pos, pytype = raw
                yield RawMessage(topic, msg_type, md5sum, data, stamp,
                                 {key: _text(header, key) for key in header}, pytype)
        except (rosbag.ROSBagException, OSError) as err:
            raise BagError(f"cannot read bag {self.path}: {err}") from None

    def _fingerprint(self) -> str:
        bag = self.bag
        connections = [(c.topic, c.datatype, c.md5sum, _text(c.header, "callerid"))
                       for c in bag._get_connections()]
        if not connections:
            return fingerprint_of(0.0, 0.0, 0, [])
        return fingerprint_of(bag.get_start_time(), bag.get_end_time(), bag.get_message_count(),
                              connections)

    def _open_unindexed(self) -> None:
        """Rebuild the index of a bag without one, as `rosbag reindex` does (module docstring)."""
        import rosbag
        from tqdm import tqdm

        try:
            bag = rosbag.Bag(str(self.path), "r", allow_unindexed=True)
        except (rosbag.ROSBagException, OSError, ValueError) as err:
            raise BagError(f"cannot read bag {self.path}: {err}") from None
        self.handle = self.bag = bag
        if bag.version != 200:
            raise BagError(f"cannot read bag {self.path}: it has no index and is of version {bag.version}; "
                           f"run `rosbag reindex` on it first")
        size = bag.size
        started = []
        with tqdm(total=size, unit="B", unit_scale=True, desc=f"reindex {self.path.name}",
                  disable=not self.progress) as bar:
            try:
                for position in bag.reindex():
                    bar.update(position - (started[-1] if started else 0))
                    started.append(position)
            except Exception:  # noqa: BLE001 - as `rosbag reindex`: reading stops at the damage
                pass  # (also rosbag's truncation after the last chunk, which fails: read-only here)
        good = set(bag._chunk_headers)
        stop = next((position for position in started if position not in good), size)
        if not good:
            raise BagError(f"cannot read bag {self.path}: it has no index and no complete chunk "
                           f"({size} bytes unreadable)")
        self._keep_complete_chunks(good)
        self.recovery = Recovery(self.count(), len({c.topic for c in bag._get_connections()}),
                                 size - stop, "unindexed bag")

    def _keep_complete_chunks(self, good) -> None:
        """Index entries of the complete chunks only; connections without messages dropped (what
        the index `rosbag reindex` writes holds)."""
        bag = self.bag
        for connection_id in list(bag._connection_indexes):
            entries = [e for e in bag._connection_indexes[connection_id] if e.chunk_pos in good]
            if entries:
                bag._connection_indexes[connection_id] = entries
            else:
                del bag._connection_indexes[connection_id]
                bag._connections.pop(connection_id, None)
        bag._topic_connections = {c.topic: c.id for c in bag._connections.values()}
        bag._connection_indexes_read = True


class BagWriter(FileWriter):
    """Writes stored messages to a new bag, one bag connection per topic info (publisher and
    source). rosbag's Python writer keeps one connection per topic (the first header wins), so
    the writer's current connection of a topic is switched before each write (rosbag's
    `_topic_connections`, as in ROS Noetic's rosbag)."""

    format_name = "bag"
    compressions = ("none", "bz2", "lz4")

    def _open(self, path: Path) -> None:
        import rosbag

        try:
            self.bag = rosbag.Bag(str(path), "w", compression=self.compression)
        except (rosbag.ROSBagException, OSError, ValueError) as err:
            raise BagError(f"cannot write bag {path}: {err}") from None
        self.by_info: Dict[tuple, object] = {}
        self.types: Dict[str, Tuple[str, str]] = {}
        self.switch = isinstance(getattr(self.bag, "_topic_connections", None), dict)

    def _close(self) -> None:
        self.bag.close()

    def write(self, info, stored) -> None:
        earlier = self.types.setdefault(stored.topic, (info.msg_type, info.md5sum))
        if earlier != (info.msg_type, info.md5sum):
            raise BagError(f"topic {stored.topic} holds both {earlier[0]} and {stored.msg_type}; a bag "
                           f"keeps one type per topic: export them separately with a type filter")
        header = {"topic": info.topic, "type": info.msg_type, "md5sum": info.md5sum,
                  "message_definition": info.definition, "latching": "1" if info.latching else "0"}
        if info.callerid:
            header["callerid"] = info.callerid
        stub = type("StoredType", (), {"_type": info.msg_type, "_md5sum": info.md5sum,
                                       "_full_text": info.definition})
        if self.switch:
            connection = self.by_info.get(info.key)
            if connection is not None:
                self.bag._topic_connections[stored.topic] = connection
            else:
                self.bag._topic_connections.pop(stored.topic, None)
        self.bag.write(stored.topic, (stored.msg_type, stored.raw, stored.md5sum, None, stub),
                       t=stored.receive_stamp, raw=True, connection_header=header)
        if self.switch and info.key not in self.by_info:
            self.by_info[info.key] = self.bag._topic_connections[stored.topic]


register_format(FileFormat("bag", BagReader, BagWriter, (".bag", ".active"), BAG_MAGIC,
                           BagWriter.compressions))
