"""The quarantine file: messages the database refused on their own merits, kept for the operator.

Only a single document the server refuses alone (after its batch was split down to it) lands here,
e.g. CouchDB's 413 `document_too_large` when `max_document_size` is lower than the message. The
file has the spool's framed format (ros_mongo.recording.spool: a topic info before the first message of each
topic), so nothing is lost and it can be inspected and stored again once the cause is fixed:

    python3 -m ros_mongo.recording.quarantine list FILE
    python3 -m ros_mongo.recording.quarantine import FILE --db-url URL

(or start the recorder with `~spool_path:=FILE`: it drains a spool-format file into the database).
"""
import argparse
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

from ros_mongo.errors import DocumentsRejected, StoreError
from ros_mongo.recording.spool import Spool, read_entries
from ros_mongo.records import MessageRecord, TopicInfo
from ros_mongo.storage.chunks import ChunkRecord
from ros_mongo.storage.store import MessageStore, open_store

__all__ = ["Quarantine", "import_quarantine", "main"]


class Quarantine:
    """Appends refused records (each with its topic info the first time) to a spool-format file."""

    def __init__(self, path: Union[str, Path], *, fsync: bool = False, min_free_bytes: int = 0):
        self.path = Path(path)
        self._file = Spool(self.path, fsync=fsync, max_bytes=1 << 62, min_free_bytes=min_free_bytes)
        self._written_topics: set = set()
        self._opened = False

    def add(self, records: Sequence[MessageRecord], topics: Dict[Tuple[str, str, str], TopicInfo]) -> None:
        """Append `records` (SpoolError when the file cannot be written)."""
        if not self._opened:
            self._file.open()
            self._opened = True
        entries: List[Union[TopicInfo, MessageRecord]] = []
        for record in records:
            key = (record.topic, record.msg_type, record.md5sum)
            if key not in self._written_topics and key in topics:
                entries.append(topics[key])
                self._written_topics.add(key)
            entries.append(record)
        self._file.append(entries)

    def close(self) -> None:
        self._file.close()


def import_quarantine(path: Union[str, Path], store: MessageStore) -> Tuple[int, int]:
    """Store the messages of a quarantine (or spool) file: (stored, still refused)."""
    entries = read_entries(path)
    for entry in entries:
        if isinstance(entry, TopicInfo):
            store.put_topic(entry)
    records = [e for e in entries if isinstance(e, (MessageRecord, ChunkRecord))]
    try:
        store.insert_records(records)
    except DocumentsRejected as err:
        return len(records) - err.rejected, err.rejected
    return len(records), 0


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m ros_mongo.recording.quarantine",
                                     description="list or store again a recorder's quarantine file")
    parser.add_argument("command", choices=["list", "import"])
    parser.add_argument("file")
    parser.add_argument("--db-url", help="database URL (import)")
    args = parser.parse_args(argv)
    try:
        if args.command == "list":
            for entry in read_entries(args.file):
                if isinstance(entry, (MessageRecord, ChunkRecord)):
                    print(f"{entry.id}  {entry.topic}  {entry.msg_type}  {len(entry.raw)} bytes")
            return 0
        if not args.db_url:
            parser.error("import needs --db-url")
        with open_store(args.db_url) as store:
            stored, refused = import_quarantine(args.file, store)
        print(f"{args.file}: {stored} messages stored, {refused} still refused")
        return 0 if refused == 0 else 1
    except StoreError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
