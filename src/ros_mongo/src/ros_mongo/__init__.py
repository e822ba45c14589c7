"""The robot's data API: record ROS topics into CouchDB or MongoDB, replay them, convert bags.

    from ros_mongo import open_store
    with open_store("http://127.0.0.1:5984/robot_data") as store:
        store.insert_message("/odom", odom, tags=["odom"])
        for stored in store.find_messages(topic="/odom", start_time=t0):
            odom = stored.message()
"""
from ros_mongo.errors import (
    BagError,
    QueryError,
    SpoolError,
    StoreError,
    StoreUnavailable,
    UnknownTypeError,
)
from ros_mongo.query import Query, parse_query
from ros_mongo.records import MessageRecord, StoredMessage, TopicInfo, make_record
from ros_mongo.storage.store import MessageStore, open_store, redact_url

__all__ = [
    "open_store",
    "MessageStore",
    "StoredMessage",
    "MessageRecord",
    "TopicInfo",
    "Query",
    "parse_query",
    "make_record",
    "redact_url",
    "StoreError",
    "StoreUnavailable",
    "QueryError",
    "UnknownTypeError",
    "BagError",
    "SpoolError",
]
