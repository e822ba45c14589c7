"""One store interface over two backends, chosen by the database URL.

    store = open_store("http://127.0.0.1:5984/robot_data")      # CouchDB (the default backend)
    store = open_store("mongodb://127.0.0.1:27017/robot_data")  # MongoDB (pymongo 4, GridFS)

The store API is `ros_mongo.backends.base.MessageStore`; the backends register themselves for
their URL schemes when `ros_mongo.backends` is imported (as here).
"""
import logging

from ros_mongo.backends import BLOB_THRESHOLD, MessageStore, backend_for_url, redact_url

__all__ = ["MessageStore", "open_store", "redact_url", "BLOB_THRESHOLD"]

log = logging.getLogger(__name__)


def open_store(url: str, *, connect: bool = True, **options) -> MessageStore:
    """A store for `url`: http(s):// is CouchDB, mongodb:// (or mongodb+srv://) is MongoDB.

    Args:
        connect: create the database and indexes now (StoreUnavailable if the server is down);
            with False the first operation does it (the recorder starts while the server is down).
        options: blob_threshold, max_array_len, timeout (seconds).
    """
    store = backend_for_url(url)(url, **options)
    store._reopen_args = (url, dict(options))
    if connect:
        try:
            store.connect()
        except BaseException:
            store.close()
            raise
    log.debug("opened %s", store)
    return store
