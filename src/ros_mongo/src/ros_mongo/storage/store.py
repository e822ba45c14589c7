"""One store interface over two backends, chosen by the database URL.

    store = open_store("http://127.0.0.1:5984/robot_data")      # CouchDB (the default backend)
    store = open_store("mongodb://127.0.0.1:27017/robot_data")  # MongoDB (pymongo 4, GridFS)

The store API is `ros_mongo.storage.base.MessageStore`; the backends register themselves for
their URL schemes when `ros_mongo.storage.backends` is imported (as here).

Credentials: keep the URL password-free and give the password through `credentials_file` or the
environment (ROS_MONGO_DB_PASSWORD, ROS_MONGO_DB_USER; see `ros_mongo.urls`). Errors and logs only
ever show the redacted URL.
"""
import logging
from typing import Optional

from ros_mongo.storage.backends import BLOB_THRESHOLD, MessageStore, backend_for_url, redact_url
from ros_mongo.urls import check_url, with_credentials

__all__ = ["MessageStore", "open_store", "redact_url", "BLOB_THRESHOLD"]

log = logging.getLogger(__name__)


def open_store(url: str, *, connect: bool = True, credentials_file: Optional[str] = None,
               warn_password: bool = True, **options) -> MessageStore:
    """A store for `url`: http(s):// is CouchDB, mongodb:// (or mongodb+srv://) is MongoDB.

    Args:
        connect: create the database and indexes now (StoreUnavailable if the server is down);
            with False the first operation does it (the recorder starts while the server is down).
        credentials_file: a file holding 'user:password' or 'password' (see ros_mongo.urls);
            without it the password may come from ROS_MONGO_DB_PASSWORD.
        warn_password: warn once when `url` itself carries a password (it shows in roslaunch's
            parameter summary); the store's `reopen_args()` turn it off, their URL holds the
            credentials this process added.
        options: blob_threshold, max_array_len, timeout (seconds).
    """
    check_url(url)
    url = with_credentials(url, credentials_file=credentials_file, warn=warn_password)
    store = backend_for_url(url)(url, **options)
    store._reopen_args = (url, dict(options, warn_password=False))
    if connect:
        try:
            store.connect()
        except BaseException:
            store.close()
            raise
    log.debug("opened %s", store)
    return store
