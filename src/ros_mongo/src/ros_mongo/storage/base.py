"""The store every backend is: the user-facing API written once over a few backend primitives,
and the registry that picks a backend from a database URL's scheme.

A backend subclasses `MessageStore`, implements its primitives (`_setup`, `_batch_item`,
`_write_batch`, `_put_topic_doc`, `_topic_docs`, `_docs`, `_count`, `_load_blob`, `ping`,
`close`, and `ensure_indexes` where it has indexes) and registers itself for its URL schemes with
`register_backend`. Everything users call lives here; the stored document layout is in
`ros_mongo.storage.documents`. This module imports no backend: `ros_mongo.storage.backends`
imports each one, and each registers itself on import; a backend whose client library is costly
to import (MongoDB's pymongo) is named with `register_backend_module` instead and imported the
first time a URL of its schemes is opened.

Write errors (taxonomy in ros_mongo.errors): `_write_batch` raises StoreUnavailable (retry later),
StoreRefused (operator must act) or BatchTooLarge (refused as a whole because of one document:
`_insert` splits the batch until that document is alone), and reports documents refused on their
own merits as "<id>: <reason>" strings; `insert_records` stores every other document, then raises
one DocumentsRejected naming the refused ids.
"""
import abc
import importlib
import threading
import time
from io import BytesIO
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Tuple, Type, TypeVar, Union

import ros_mongo.messages.msgtypes as msgtypes
from ros_mongo.errors import (
    BatchTooLarge,
    DocumentsRejected,
    QueryError,
    StoreError,
    StoreRefused,
    StoreUnavailable,
    UnknownTypeError,
)
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, StoredMessage, TopicInfo, make_record, split_time
from ros_mongo.storage.documents import stored_message, topic_from_doc
from ros_mongo.urls import check_url, redact_url

__all__ = ["MessageStore", "PreparedRecords", "BLOB_THRESHOLD", "redact_url", "register_backend",
           "register_backend_module", "backend_for_url", "registered_schemes"]

#: Serialized messages larger than this go to attachments (CouchDB) or GridFS (MongoDB).
BLOB_THRESHOLD = 256 * 1024


class MessageStore(abc.ABC):
    """Stores ROS messages with their metadata (document layout: ros_mongo.storage.documents).

    Args:
        url: the database URL (credentials are never logged).
        blob_threshold: serialized sizes above this go to attachments / GridFS.
        max_array_len: longer arrays are not decoded into the queryable fields.
    """

    backend = "none"
    backend_title = "the database"      # in error messages
    batch_docs = 1000                   # documents per batched write, at most
    batch_bytes = 24 * 1024 * 1024      # bytes per batched write, about

    def __init__(self, url: str, *, blob_threshold: int = BLOB_THRESHOLD,
                 max_array_len: int = msgtypes.MAX_ARRAY_LEN):
        self.url = redact_url(url)
        self.blob_threshold = int(blob_threshold)
        self.max_array_len = int(max_array_len)
        self._ready = False
        self._ready_lock = threading.Lock()
        self._known_topics: Dict[str, TopicInfo] = {}
        self._definitions: Dict[Tuple[str, str], str] = {}
        # how to open this database again (holds credentials: never log it)
        self._reopen_args = (url, {"blob_threshold": self.blob_threshold,
                                   "max_array_len": self.max_array_len})

    def reopen_args(self) -> Tuple[str, dict]:
        """(url, options) for `open_store` to reach the same database from another process.
        The URL keeps its credentials: pass it on, never log it."""
        return self._reopen_args

    # -- set-up ------------------------------------------------------------------------------
    def connect(self) -> "MessageStore":
        """Create the database and its indexes if needed (StoreUnavailable when unreachable)."""
        with self._ready_lock:
            if not self._ready:
                self._setup()
                self._ready = True
        return self

    def _ensure(self) -> None:
        if not self._ready:
            self.connect()

    # -- writing -----------------------------------------------------------------------------
    def insert_message(self, topic: str, msg, *, tags: Sequence[str] = (),
                       receive_time: Optional[float] = None, session_id: Optional[str] = None,
                       robot_id: Optional[str] = None) -> str:
        """Store one genpy message; returns its id once it is durably stored."""
        cls = msg.__class__
        if not hasattr(cls, "_md5sum") or not hasattr(msg, "serialize"):
            raise StoreError(f"not a ROS message: {msg!r:.80}")
        if isinstance(tags, str):
            tags = [tags]
        raw = _serialize(msg)
        receive = split_time(time.time() if receive_time is None else receive_time)
        record = make_record(topic, cls, raw, receive=receive, tags=tags, session_id=session_id,
                             robot_id=robot_id, message=msg, max_array_len=self.max_array_len)
        self.put_topic(TopicInfo.of_class(topic, cls))
        self.insert_records([record])
        return record.id

    def insert_records(self, records: Sequence[MessageRecord], *, look_up: bool = True) -> int:
        """Store records in batches; ids already stored are skipped (so retries store each once).

        Returns the number of records newly stored. Their topic infos must be put first.
        `look_up` False: documents with attachments are written without looking up first which
        are stored already (a CouchDB request saved per batch: the recorder's writes). Each is
        still stored once (a write of a stored one changes nothing), but the count then includes
        them, and a document stored by a release before 2026-11-24 (a revision the server made)
        gets the same content as a second revision.
        """
        if not records:
            return 0
        self._ensure()
        return self.insert_prepared(self.prepare_records(records), look_up=look_up)

    def prepare_records(self, records: Sequence[MessageRecord]) -> "PreparedRecords":
        """The records encoded as this backend writes them, without any I/O (so a caller can
        encode the next records on its thread while another thread writes: `insert_prepared`).
        A record that cannot be encoded at all is kept as an error, reported by `insert_prepared`."""
        prepared = PreparedRecords(len(records))
        for record in records:
            try:
                item, weight = self._batch_item(record)
            except (StoreUnavailable, StoreRefused):
                raise
            except StoreError as err:  # cannot be encoded at all: invalid on its own merits
                prepared.errors.append(f"{record.id}: {err}")
                continue
            prepared.items.append((item, record.id, weight))
        return prepared

    def insert_prepared(self, prepared: "PreparedRecords", *, look_up: bool = True) -> int:
        """`insert_records` for records `prepare_records` encoded (same contract)."""
        if not prepared.records:
            return 0
        self._ensure()
        return self._insert(prepared, look_up)

    def put_topic(self, info: TopicInfo) -> None:
        """Keep a topic's definition and latching (once per topic, type and md5sum)."""
        if info.id in self._known_topics:
            return
        self._ensure()
        self._put_topic_doc(info)
        self._known_topics[info.id] = info
        self._definitions[(info.msg_type, info.md5sum)] = info.definition

    # -- reading -----------------------------------------------------------------------------
    def topics(self) -> List[TopicInfo]:
        """Every stored topic info, sorted by topic."""
        self._ensure()
        infos = [topic_from_doc(doc) for doc in self._topic_docs()]
        for info in infos:
            self._definitions[(info.msg_type, info.md5sum)] = info.definition
        return sorted(infos, key=lambda i: (i.topic, i.msg_type))

    def find_messages(self, *, topic: Union[str, Sequence[str], None] = None,
                      msg_type: Optional[str] = None, tags: Union[str, Sequence[str], None] = None,
                      session_id: Optional[str] = None, robot_id: Optional[str] = None,
                      start_time: Optional[float] = None, end_time: Optional[float] = None,
                      fields: Optional[dict] = None, newest_first: bool = False,
                      limit: Optional[int] = None) -> Iterator[StoredMessage]:
        """Stored messages matching every criterion, by receive time (QueryError if malformed)."""
        query = Query.build(topic=topic, msg_type=msg_type, tags=tags, session_id=session_id,
                            robot_id=robot_id, start_time=start_time, end_time=end_time, fields=fields)
        return self.find(query, newest_first=newest_first, limit=limit)

    def find(self, query: Query, *, newest_first: bool = False, limit: Optional[int] = None,
             decoded: bool = True) -> Iterator[StoredMessage]:
        """Like find_messages, with a prepared Query; `decoded=False` leaves out the decoded fields
        (less to transfer when only the bytes are wanted, as in a replay)."""
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 0):
            raise QueryError(f"limit must be a non-negative integer, got {limit!r}")
        self._ensure()
        docs = self._docs(query, newest_first, limit, decoded)
        return (self._stored(doc, raw) for doc, raw in docs)

    def count(self, query: Optional[Query] = None) -> int:
        """How many stored messages match `query` (all when None)."""
        self._ensure()
        return self._count(query or Query())

    def count_messages(self, **criteria) -> int:
        """count() with find_messages' keywords."""
        return self.count(Query.build(**criteria))

    def message_class(self, msg_type: str, md5sum: str) -> type:
        """The class for a stored type: installed, or generated from the stored definition."""
        try:
            return msgtypes.message_class(msg_type, md5sum)
        except UnknownTypeError:
            pass
        definition = self._definitions.get((msg_type, md5sum))
        if definition is None:
            self.topics()
            definition = self._definitions.get((msg_type, md5sum))
        return msgtypes.message_class(msg_type, md5sum, definition)

    def _stored(self, doc: dict, raw: Optional[bytes]) -> StoredMessage:
        return stored_message(doc, raw, self._load_blob, self.message_class)

    # -- backend primitives ---------------------------------------------------------------------
    @abc.abstractmethod
    def _setup(self) -> None:
        """Create the database and its indexes if needed."""

    def ensure_indexes(self) -> bool:
        """Create the indexes / design documents reads use, if this account may (once; tolerant of
        another client creating them at the same time). True when they exist afterwards, False when
        the account may not create them (reads still work, slower). StoreUnavailable when the server
        cannot be reached. Backends with indexes override this; `ros_mongo_bag setup` calls it with
        an admin URL."""
        return True

    def _insert(self, prepared: "PreparedRecords", look_up: bool = True) -> int:
        """Write prepared records in batches of at most `batch_docs` documents and about `batch_bytes`.

        A batch refused as a whole because of one document (BatchTooLarge) is split until that
        document is alone; documents refused on their own merits are collected and reported
        together, after every other document was stored, as one DocumentsRejected naming them.
        StoreUnavailable / StoreRefused pass through (nothing is lost: ids dedupe the retry)."""
        stored, errors, batch, size = 0, list(prepared.errors), [], 0
        for item, record_id, weight in prepared.items:
            if batch and (len(batch) >= self.batch_docs or size + weight > self.batch_bytes):
                stored += self._write_split(batch, errors, look_up)
                batch, size = [], 0
            batch.append((item, record_id))
            size += weight
        if batch:
            stored += self._write_split(batch, errors, look_up)
        if errors:
            ids = frozenset(e.split(":", 1)[0] for e in errors)
            raise DocumentsRejected(f"{self.backend_title} rejected {len(errors)} of {prepared.records} "
                                    f"documents, first: {errors[0]}", len(errors), ids)
        return stored

    def _write_split(self, batch: List[Tuple[object, str]], errors: list, look_up: bool = True) -> int:
        """`_write_batch`, splitting a batch refused as a whole around the document it names
        (or in halves) until that document is alone; a lone refused document goes to `errors`."""
        try:
            return self._write_batch([item for item, _ in batch], errors, look_up=look_up)
        except BatchTooLarge as err:
            if len(batch) == 1:
                errors.append(f"{batch[0][1]}: {err}")
                return 0
            ids = [doc_id for _, doc_id in batch]
            if err.doc_id in ids:
                at = ids.index(err.doc_id)
                parts = [batch[:at], batch[at:at + 1], batch[at + 1:]]
            else:
                parts = [batch[:len(batch) // 2], batch[len(batch) // 2:]]
            return sum(self._write_split(part, errors, look_up) for part in parts if part)

    @abc.abstractmethod
    def _batch_item(self, record: MessageRecord) -> Tuple[object, int]:
        """What a batch holds for `record`, and how many bytes it adds to the batch (encoding
        only, no I/O: `_write_batch` does the writing)."""

    @abc.abstractmethod
    def _write_batch(self, batch: list, errors: list, *, look_up: bool = True) -> int:
        """Write one batch; append "<id>: <reason>" of each document refused on its own merits to
        `errors`; return how many were newly stored (see `insert_records` for `look_up`). Raises
        StoreUnavailable (retry later), StoreRefused (operator must act) or BatchTooLarge (refused
        as a whole, see `_insert`)."""

    @abc.abstractmethod
    def _put_topic_doc(self, info: TopicInfo) -> None:
        """Store a topic document unless it is stored already."""

    @abc.abstractmethod
    def _topic_docs(self) -> List[dict]:
        """Every stored topic document."""

    @abc.abstractmethod
    def _docs(self, query: Query, newest_first: bool, limit: Optional[int],
              decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        """(document, inline bytes or None) of each match, sorted by receive time."""

    @abc.abstractmethod
    def _count(self, query: Query) -> int:
        """How many stored messages match `query`."""

    @abc.abstractmethod
    def _load_blob(self, message_id: str) -> bytes:
        """The bytes kept apart from a message's document (attachment / GridFS)."""

    @abc.abstractmethod
    def ping(self) -> None:
        """Raise StoreUnavailable unless the server answers."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release connections (the store can not be used afterwards)."""

    def __enter__(self) -> "MessageStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"


class PreparedRecords:
    """Records encoded for one backend (`MessageStore.prepare_records`): `items` (backend item,
    record id, bytes it weighs), `errors` ("<id>: <reason>" of records that cannot be encoded) and
    how many `records` were given."""

    __slots__ = ("items", "errors", "records")

    def __init__(self, records: int):
        self.items: List[Tuple[object, str, int]] = []
        self.errors: List[str] = []
        self.records = records


def _serialize(msg) -> bytes:
    buffer = BytesIO()
    try:
        msg.serialize(buffer)
    except Exception as err:  # noqa: BLE001 - genpy raises SerializationError, struct.error...
        raise StoreError(f"cannot serialize {msg.__class__._type} message: {err}") from err
    return buffer.getvalue()


# -- the backend registry ------------------------------------------------------------------------
StoreT = TypeVar("StoreT", bound=Type[MessageStore])
_BACKENDS: Dict[str, Type[MessageStore]] = {}
_BACKEND_MODULES: Dict[str, str] = {}   # scheme -> module that registers its backend on import


def register_backend(*schemes: str) -> Callable[[StoreT], StoreT]:
    """Class decorator: the backend stores URLs with these schemes ("http", "mongodb", ...)."""
    def register(store_cls: StoreT) -> StoreT:
        for scheme in schemes:
            owner = _BACKENDS.get(scheme.lower())
            if owner is not None and owner is not store_cls:
                raise StoreError(f"URL scheme {scheme!r} is taken by {owner.__name__}")
            _BACKENDS[scheme.lower()] = store_cls
        return store_cls
    return register


def register_backend_module(module: str, *schemes: str) -> None:
    """The backend of these schemes lives in `module` (which registers it with `register_backend`)
    and is imported, with its client library, the first time it is needed."""
    for scheme in schemes:
        _BACKEND_MODULES.setdefault(scheme.lower(), module)


def _import_backends(scheme: Optional[str] = None) -> None:
    """Import the not yet imported backend module of `scheme` (None: of every scheme)."""
    wanted = [scheme] if scheme is not None else sorted(_BACKEND_MODULES)
    for name in wanted:
        if name in _BACKEND_MODULES and name not in _BACKENDS:
            importlib.import_module(_BACKEND_MODULES[name])


def registered_schemes() -> Dict[str, str]:
    """URL scheme -> backend name ("couchdb", "mongodb") of every registered backend."""
    _import_backends()
    return {scheme: store_cls.backend for scheme, store_cls in sorted(_BACKENDS.items())}


def backend_for_url(url: str) -> Type[MessageStore]:
    """The backend class for `url`'s scheme (StoreError for a malformed URL or unknown scheme)."""
    check_url(url)
    scheme = url.split("://", 1)[0].lower()
    _import_backends(scheme)
    store_cls = _BACKENDS.get(scheme)
    if store_cls is None:
        _import_backends()
        uses = {}
        for known, owner in _BACKENDS.items():
            uses.setdefault(owner.backend_title, []).append(known + "://")
        hint = " or ".join(f"{', '.join(prefixes)} for {title}" for title, prefixes in uses.items())
        raise StoreError(f"unsupported database URL scheme {scheme!r} in {redact_url(url)} "
                         f"(use {hint or 'a registered backend'})")
    return store_cls
