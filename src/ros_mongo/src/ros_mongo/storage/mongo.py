"""MongoDB backend (pymongo 4 only: insert_many, count_documents, create_index, GridFSBucket).

Layout: collection `messages` (one document per message; serialized bytes up to the blob
threshold inline as BSON binary `raw`, larger ones in the GridFS bucket `blobs` under the message
id, so no document nears MongoDB's 16 MB limit), collection `topics` (one document per topic and
type). Indexes on (topic, receive_time), (receive_time), (session_id, receive_time) and tags.
Writes use write concern {w: 1, j: true}: an insert returns once it is journaled.
"""
import logging
from typing import Callable, Iterator, List, Optional, Tuple, TypeVar

import bson
import gridfs
import pymongo
from bson.binary import Binary
from pymongo import errors as mongo_errors
from pymongo.write_concern import WriteConcern

from ros_mongo.errors import BatchTooLarge, QueryError, StoreError, StoreRefused, StoreUnavailable
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo
from ros_mongo.storage.base import MessageStore, register_backend
from ros_mongo.storage.documents import message_doc, query_conditions, to_selector, topic_doc
from ros_mongo.urls import scrub

__all__ = ["MongoStore", "MAX_BSON_BYTES", "INDEXES"]

log = logging.getLogger(__name__)

MAX_BSON_BYTES = 16 * 1024 * 1024 - 64 * 1024
#: name -> keys of the secondary indexes on `messages` (the sort uses the `_id` index)
INDEXES = {
    "ros_mongo_time": [("receive_time", 1)],
    "ros_mongo_topic_time": [("topic", 1), ("receive_time", 1)],
    "ros_mongo_session_time": [("session_id", 1), ("receive_time", 1)],
    "ros_mongo_robot_time": [("robot_id", 1), ("receive_time", 1)],
    "ros_mongo_tags": [("tags", 1)],
}
_DUPLICATE_KEY = 11000
_UNAUTHORIZED = (13, 18, 8000)        # Unauthorized, AuthenticationFailed, AtlasError (Atlas' refusal)
_RETRY_CODES = (50, 64, 91, 189, 6, 7, 89, 9001, 10107, 11600, 11602, 13435, 13436, 262)
_INDEX_CONFLICTS = (68, 85, 86)        # IndexAlreadyExists, IndexOptionsConflict, IndexKeySpecsConflict
_LOST = object()
T = TypeVar("T")


@register_backend("mongodb", "mongodb+srv")
class MongoStore(MessageStore):
    """Messages in a MongoDB database (URL mongodb://[user:pass@]host:port/dbname[?options])."""

    backend = "mongodb"
    backend_title = "MongoDB"
    batch_bytes = 32 * 1024 * 1024
    read_page = 500   # documents per read query

    def __init__(self, url: str, *, timeout: float = 10.0, **options):
        super().__init__(url, **options)
        settings = {"connect": False}
        if "serverselectiontimeoutms" not in url.lower():
            settings["serverSelectionTimeoutMS"] = int(timeout * 1000)
        if "connecttimeoutms" not in url.lower():
            settings["connectTimeoutMS"] = int(timeout * 1000)
        try:
            self.client = pymongo.MongoClient(url, **settings)
            self.db = self.client.get_default_database(default="robot_data")
        except (mongo_errors.PyMongoError, ValueError, TypeError) as err:
            raise StoreError(f"bad MongoDB URL {self.url}: {scrub(str(err), url)}") from None
        self._secret_url = url  # only to scrub the password out of driver messages
        self._indexes_tried = False
        self._index_warned = False
        # the URL's write concern (w=majority, journal=true, wtimeoutMS) when it has one
        durable = self.client.write_concern if self.client.write_concern.document \
            else WriteConcern(w=1, j=True)
        self.write_concern = durable
        self.messages = self.db.get_collection("messages", write_concern=durable)
        self.topic_docs = self.db.get_collection("topics", write_concern=durable)
        self.blobs = gridfs.GridFSBucket(self.db, bucket_name="blobs", write_concern=durable)

    def _call(self, what: str, action: Callable[[], T], *, query: bool = False) -> T:
        try:
            return action()
        except StoreError:
            raise
        except Exception as err:  # noqa: BLE001 - any driver failure becomes a clear StoreError
            raise self._translate(what, err, query) from None

    def _translate(self, what: str, err: BaseException, query: bool = False) -> StoreError:
        """The StoreError for a driver exception (never holding the password)."""
        if isinstance(err, (mongo_errors.ConnectionFailure, mongo_errors.WTimeoutError)):
            return StoreUnavailable(f"MongoDB at {self.url} is unreachable: {type(err).__name__}")
        if isinstance(err, mongo_errors.ConfigurationError):
            return StoreRefused(f"MongoDB at {self.url}: {scrub(str(err), self._secret_url)}")
        if isinstance(err, mongo_errors.OperationFailure):
            message = scrub((err.details or {}).get("errmsg") or str(err), self._secret_url)
            if err.code in _UNAUTHORIZED:
                return StoreRefused(f"MongoDB at {self.url} refused to {what}: {message} "
                                    f"(code {err.code}: check the account's roles and password)")
            if err.code in _RETRY_CODES:
                return StoreUnavailable(f"MongoDB at {self.url} could not {what} now: {message}")
            error_class = QueryError if query else StoreError
            return error_class(f"MongoDB refused to {what}: {message}")
        if not isinstance(err, (mongo_errors.PyMongoError, bson.errors.BSONError, OverflowError)):
            # not a documented driver error (e.g. a server answering an unexpected shape)
            return StoreRefused(f"MongoDB at {self.url}: the driver failed to {what}: "
                                f"{type(err).__name__}: {scrub(str(err), self._secret_url)}")
        return StoreError(f"MongoDB failed to {what}: {type(err).__name__}: "
                          f"{scrub(str(err), self._secret_url)}")

    def ping(self) -> None:
        self._call("answer ping", lambda: self.client.admin.command("ping"))

    def _setup(self) -> None:
        """Reachability only: reading creates nothing (see ensure_indexes)."""
        self.ping()

    def ensure_indexes(self) -> bool:
        """Create the indexes (`INDEXES`) unless they exist, tolerant of other clients creating
        them at the same time. True when they exist afterwards, False when the account may not
        create them (Unauthorized); StoreUnavailable when the server cannot be reached."""
        def create() -> bool:
            for name, keys in INDEXES.items():
                try:
                    self.messages.create_index(keys, name=name)
                except mongo_errors.OperationFailure as err:
                    if err.code in _UNAUTHORIZED:
                        return False
                    if err.code not in _INDEX_CONFLICTS:
                        raise
            return True
        return self._call("create indexes", create)

    def _indexes_once(self) -> None:
        """Before the first write: create the indexes if the account may (once; a refusal is
        logged once and recording goes on)."""
        if self._indexes_tried:
            return
        try:
            made = self.ensure_indexes()
        except StoreUnavailable:
            return  # the write that follows reports it; try again next time
        except StoreError as err:
            log.warning("MongoDB %s: cannot create indexes (%s); recording goes on", self.url, err)
            made = True
        if not made:
            log.warning("MongoDB %s: this account may not create indexes; recording goes on and reads "
                        "filter more slowly until 'ros_mongo_bag setup --db-url <admin url>' creates "
                        "them", self.url)
        self._index_warned = True
        self._indexes_tried = True

    def close(self) -> None:
        self.client.close()

    # -- writing -----------------------------------------------------------------------------
    def _batch_item(self, record: MessageRecord) -> Tuple[Tuple[dict, Optional[bytes]], int]:
        """(document, bytes for GridFS or None), and the bytes the document holds."""
        doc = message_doc(record)
        if len(record.raw) > self.blob_threshold:
            doc["blob"] = True
            if len(bson.encode(doc)) > MAX_BSON_BYTES:
                doc["msg"], doc["fields_dropped"] = None, True
            return (doc, record.raw), 0
        doc["raw"] = Binary(record.raw)
        return (doc, None), len(record.raw)

    def _put_blobs(self, blobs: List[Tuple[str, bytes]]) -> None:
        """GridFS files for the messages not stored there yet (one lookup for them all; chunks of
        a torn earlier attempt are removed first), before their documents are inserted."""
        def put() -> None:
            ids = [message_id for message_id, _ in blobs]
            present = {doc["_id"] for doc in self.db["blobs.files"].find({"_id": {"$in": ids}}, {"_id": 1})}
            missing = [(message_id, raw) for message_id, raw in blobs if message_id not in present]
            if not missing:
                return
            self.db["blobs.chunks"].delete_many({"files_id": {"$in": [m for m, _ in missing]}})
            for message_id, raw in missing:
                self.blobs.upload_from_stream_with_id(message_id, message_id, raw)
        self._call("store message bytes in GridFS", put)

    def _write_batch(self, items: List[Tuple[dict, Optional[bytes]]], errors: list, *,
                     look_up: bool = True) -> int:
        """(`look_up` changes nothing here: duplicate ids are refused, so the count is exact.)"""
        self._indexes_once()
        blobs = [(doc["_id"], raw) for doc, raw in items if raw is not None]
        if blobs:
            self._put_blobs(blobs)
        docs = [doc for doc, _ in items]

        def insert() -> int:
            try:
                return len(self.messages.insert_many(docs, ordered=False).inserted_ids)
            except mongo_errors.BulkWriteError as err:  # duplicates: stored by an earlier attempt
                details = err.details or {}
                if details.get("writeConcernErrors"):
                    first = details["writeConcernErrors"][0]
                    raise StoreUnavailable(f"MongoDB at {self.url} did not make the write durable: "
                                           f"{first.get('errmsg')}") from None
                for error in details.get("writeErrors", []):
                    if error.get("code") in _UNAUTHORIZED:
                        raise StoreRefused(f"MongoDB at {self.url} refused to insert messages: "
                                           f"{error.get('errmsg')}") from None
                errors.extend(f"{e.get('op', {}).get('_id')}: {e.get('errmsg')}"
                              for e in details.get("writeErrors", []) if e.get("code") != _DUPLICATE_KEY)
                return int(details.get("nInserted", 0))
        try:
            return insert()
        except (bson.errors.BSONError, OverflowError, mongo_errors.DocumentTooLarge) as err:
            # found by the driver before the server saw it: the base class splits the batch
            # until the document is alone, then reports it
            first = docs[0].get("_id") if len(docs) == 1 else None
            raise BatchTooLarge(f"MongoDB cannot hold {'document ' + str(first) if first else 'a document'} "
                                f"as BSON: {type(err).__name__}: {scrub(str(err), self._secret_url)}",
                                first) from None
        except StoreError:
            raise
        except Exception as err:  # noqa: BLE001 - any driver failure becomes a clear StoreError
            raise self._translate("insert messages", err) from None

    def _put_topic_doc(self, info: TopicInfo) -> None:
        self._indexes_once()

        def put() -> None:
            try:
                self.topic_docs.insert_one(topic_doc(info))
            except mongo_errors.DuplicateKeyError:
                pass
        self._call("store a topic", put)

    # -- reading -----------------------------------------------------------------------------
    def _topic_docs(self) -> List[dict]:
        return self._call("list topics", lambda: list(self.topic_docs.find({})))

    def _docs(self, query: Query, newest_first: bool, limit: Optional[int],
              decoded: bool) -> Iterator[Tuple[dict, Optional[bytes]]]:
        """Page by page: each page a new query continuing after the last `_id` read."""
        if limit == 0:
            return
        self._check_indexes()
        direction = pymongo.DESCENDING if newest_first else pymongo.ASCENDING
        projection = None if decoded else {"msg": 0}
        base = _filter(query)
        sort = [("_id", direction)]
        last: Optional[str] = None
        yielded, fruitless = 0, 0
        while limit is None or yielded < limit:
            want = self.read_page if limit is None else min(self.read_page, limit - yielded)
            after = {"_id": {"$lt" if newest_first else "$gt": last}}
            selector = base if last is None else {"$and": [base, after]} if base else after
            cursor = self.messages.find(selector, projection, sort=sort, limit=want,
                                        batch_size=min(want, 200))
            iterator = iter(cursor)
            got = 0
            while True:
                doc = self._next(iterator)
                if doc is None or doc is _LOST:
                    break
                got += 1
                last = doc["_id"]
                raw = doc.get("raw")
                yield doc, (bytes(raw) if raw is not None else None)
            cursor.close()
            yielded += got
            if doc is _LOST:  # the server dropped the cursor (idle timeout, killCursors): go on
                fruitless = 0 if got else fruitless + 1
                if fruitless > 3:
                    raise StoreError(f"MongoDB at {self.url} keeps losing the read cursor")
                log.info("MongoDB cursor lost after %d documents; continuing after the last one read",
                         yielded)
                continue
            if got < want:
                return

    def _next(self, iterator):
        """The cursor's next document, None at its end, _LOST if the server lost the cursor."""
        try:
            return next(iterator, None)
        except mongo_errors.CursorNotFound:
            return _LOST
        except Exception as err:  # noqa: BLE001 - any driver failure becomes a clear StoreError
            raise self._translate("find messages", err, query=True) from None

    def _check_indexes(self) -> None:
        """Say once when the secondary indexes are missing (reads work, filtering is slower)."""
        if self._index_warned:
            return
        self._index_warned = True
        try:
            have = [[(k, int(d)) for k, d in index["key"].items()] for index in self.messages.list_indexes()]
        except (mongo_errors.PyMongoError, KeyError, TypeError, ValueError):
            return
        missing = sorted(name for name, keys in INDEXES.items() if keys not in have)
        if missing and have:
            log.warning("MongoDB %s lacks the indexes %s: reads work but filter more slowly; "
                        "'ros_mongo_bag setup --db-url <admin url>' creates them", self.url, missing)

    def _count(self, query: Query) -> int:
        return self._call("count messages", lambda: self.messages.count_documents(_filter(query)),
                          query=True)

    def _load_blob(self, message_id: str) -> bytes:
        def load() -> bytes:
            try:
                return self.blobs.open_download_stream(message_id).read()
            except gridfs.errors.NoFile:
                raise StoreError(f"message {message_id} has no stored bytes in {self.url}") from None
        return self._call("read message bytes from GridFS", load)


def _filter(query: Query) -> dict:
    return to_selector(query_conditions(query))
