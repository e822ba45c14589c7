"""The storage backends behind `MessageStore`, registered by URL scheme (importing this package
registers every one): CouchDB (http://, https://) and MongoDB (mongodb://, mongodb+srv://)."""
from ros_mongo.storage.base import (
    BLOB_THRESHOLD,
    MessageStore,
    backend_for_url,
    redact_url,
    register_backend,
    registered_schemes,
)
from ros_mongo.storage.couch import CouchStore
from ros_mongo.storage.mongo import MongoStore

__all__ = ["MessageStore", "CouchStore", "MongoStore", "BLOB_THRESHOLD", "register_backend",
           "backend_for_url", "registered_schemes", "redact_url"]
