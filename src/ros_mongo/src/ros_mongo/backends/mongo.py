"""MongoDB backend (pymongo 4 only: insert_many, count_documents, create_index, GridFSBucket).

Layout: collection `messages` (one document per message; serialized bytes up to the blob
threshold inline as BSON binary `raw`, larger ones in the GridFS bucket `blobs` under the message
id, so no document nears MongoDB's 16 MB limit), collection `topics` (one document per topic and
type). Indexes on (topic, receive_time), (receive_time), (session_id, receive_time) and tags.
Writes use write concern {w: 1, j: true}: an insert returns once it is journaled.
"""
from typing import Callable, Iterator, List, Optional, Tuple, TypeVar

import bson
import gridfs
import pymongo
from bson.binary import Binary
from pymongo import errors as mongo_errors
from pymongo.write_concern import WriteConcern

from ros_mongo.backends.base import MessageStore, register_backend
from ros_mongo.documents import message_doc, query_conditions, to_selector, topic_doc
from ros_mongo.errors import QueryError, StoreError, StoreUnavailable
from ros_mongo.query import Query
from ros_mongo.records import MessageRecord, TopicInfo

__all__ = ["MongoStore", "MAX_BSON_BYTES"]

MAX_BSON_BYTES = 16 * 1024 * 1024 - 64 * 1024
_DUPLICATE_KEY = 11000
T = TypeVar("T")


@register_backend("mongodb", "mongodb+srv")
class MongoStore(MessageStore):
    """Messages in a MongoDB database (URL mongodb://[user:pass@]host:port/dbname[?options])."""

    backend = "mongodb"
    backend_title = "MongoDB"
    batch_bytes = 32 * 1024 * 1024

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
        except (mongo_errors.PyMongoError, ValueError) as err:
            raise StoreError(f"bad MongoDB URL {self.url}: {err}") from None
        durable = WriteConcern(w=1, j=True)
        self.messages = self.db.get_collection("messages", write_concern=durable)
        self.topic_docs = self.db.get_collection("topics", write_concern=durable)
        self.blobs = gridfs.GridFSBucket(self.db, bucket_name="blobs", write_concern=durable)

    def _call(self, what: str, action: Callable[[], T], *, query: bool = False) -> T:
        try:
            return action()
        except mongo_errors.ConnectionFailure as err:
            raise StoreUnavailable(f"MongoDB at {self.url} is unreachable: {type(err).__name__}") from err
        except mongo_errors.OperationFailure as err:
            error_class = QueryError if query else StoreError
            message = (err.details or {}).get("errmsg") or str(err)
            raise error_class(f"MongoDB refused to {what}: {message}") from None
        except mongo_errors.PyMongoError as err:
            raise StoreError(f"MongoDB failed to {what}: {err}") from err

    def ping(self) -> None:
        self._call("answer ping", lambda: self.client.admin.command("ping"))

    def _setup(self) -> None:
        def create() -> None:
            for keys in ([("topic", 1), ("receive_time", 1)], [("receive_time", 1)],
                         [("session_id", 1), ("receive_time", 1)], [("tags", 1)]):
                self.messages.create_index(keys)
        self._call("create indexes", create)

    def close(self) -> None:
        self.client.close()

    # -- writing -----------------------------------------------------------------------------
    def _batch_item(self, record: MessageRecord) -> Tuple[dict, int]:
        doc = self._document(record)
        return doc, len(record.raw) if "raw" in doc else 0

    def _document(self, record: MessageRecord) -> dict:
        doc = message_doc(record)
        if len(record.raw) > self.blob_threshold:
            self._put_blob(record.id, record.raw)
            doc["blob"] = True
            if len(bson.encode(doc)) > MAX_BSON_BYTES:
                doc["msg"], doc["fields_dropped"] = None, True
        else:
            doc["raw"] = Binary(record.raw)
        return doc

    def _put_blob(self, message_id: str, raw: bytes) -> None:
        def put() -> None:
            if self.db["blobs.files"].find_one({"_id": message_id}, {"_id": 1}) is not None:
                return  # stored by an earlier attempt
            self.db["blobs.chunks"].delete_many({"files_id": message_id})  # a torn earlier attempt
            self.blobs.upload_from_stream_with_id(message_id, message_id, raw)
        self._call("store message bytes in GridFS", put)

    def _write_batch(self, docs: List[dict], errors: list) -> int:
        def insert() -> int:
            try:
                return len(self.messages.insert_many(docs, ordered=False).inserted_ids)
            except mongo_errors.BulkWriteError as err:  # duplicates: stored by an earlier attempt
                details = err.details or {}
                errors.extend(f"{e.get('op', {}).get('_id')}: {e.get('errmsg')}"
                              for e in details.get("writeErrors", []) if e.get("code") != _DUPLICATE_KEY)
                return int(details.get("nInserted", 0))
        return self._call("insert messages", insert)

    def _put_topic_doc(self, info: TopicInfo) -> None:
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
        if limit == 0:
            return
        direction = pymongo.DESCENDING if newest_first else pymongo.ASCENDING
        projection = None if decoded else {"msg": 0}
        cursor = self.messages.find(_filter(query), projection)
        cursor = cursor.sort([("receive_time", direction), ("_id", direction)])
        cursor = cursor.batch_size(200)
        if limit:
            cursor = cursor.limit(limit)
        iterator = iter(cursor)
        while True:
            doc = self._call("find messages", lambda: next(iterator, None), query=True)
            if doc is None:
                return
            raw = doc.get("raw")
            yield doc, (bytes(raw) if raw is not None else None)

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
