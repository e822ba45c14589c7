"""The storage backends behind `MessageStore`, registered by URL scheme (importing this package
registers every one): CouchDB (http://, https://) and MongoDB (mongodb://, mongodb+srv://).
The MongoDB backend, and pymongo with it, is imported the first time a MongoDB URL is opened
(or `MongoStore` is asked for here): the CouchDB-only processes (every fleet robot) skip it."""
from ros_mongo.storage.base import (
    BLOB_THRESHOLD,
    MessageStore,
    backend_for_url,
    redact_url,
    register_backend,
    register_backend_module,
    registered_schemes,
)
from ros_mongo.storage.couch import CouchStore

register_backend_module("ros_mongo.storage.mongo", "mongodb", "mongodb+srv")

__all__ = ["MessageStore", "CouchStore", "BLOB_THRESHOLD", "register_backend",
           "register_backend_module", "backend_for_url", "registered_schemes", "redact_url"]


def __getattr__(name: str):
    if name == "MongoStore":
        from ros_mongo.storage.mongo import MongoStore

        return MongoStore
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
