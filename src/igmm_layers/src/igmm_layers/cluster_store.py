"""Cluster sets in the robot database (through the ros_mongo storage API).

Storage errors are re-raised as PersistenceError naming the database (credentials redacted).
"""
import datetime
from typing import Tuple

from igmm_layers.errors import PersistenceError
from igmm_layers.msg import ClusterSet
from ros_mongo import StoreError, open_store, redact_url

__all__ = ["CLUSTER_TOPIC", "TAG", "timestamp_tag", "save_cluster_set", "load_cluster_set"]

CLUSTER_TOPIC = "/igmm_layers/clusters"
TAG = "objects"


def timestamp_tag(seconds: float) -> str:
    """The timestamp tag of a saved set: UTC, ISO 8601 with microseconds."""
    moment = datetime.datetime.fromtimestamp(seconds, tz=datetime.timezone.utc)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _open(db_url: str):
    if not db_url:
        raise PersistenceError("no database configured (set the ~db_url parameter)")
    return open_store(db_url)


def _where(db_url: str) -> str:
    return redact_url(db_url)


def save_cluster_set(db_url: str, msg: ClusterSet, robot_id: str = "") -> Tuple[str, str]:
    """Store `msg` with tags "objects" and its timestamp (and the robot id, if given); returns
    (document id, timestamp tag)."""
    stamp = msg.header.stamp.to_sec()
    tag = timestamp_tag(stamp)
    try:
        with _open(db_url) as store:
            doc_id = store.insert_message(CLUSTER_TOPIC, msg, tags=(TAG, tag), receive_time=stamp,
                                         robot_id=robot_id or None)
    except StoreError as err:
        raise PersistenceError(f"could not save clusters to {_where(db_url)}: {err}") from err
    return doc_id, tag


def load_cluster_set(db_url: str, timestamp: str = "") -> Tuple[ClusterSet, str, str]:
    """The latest saved set, or the one with this timestamp tag: (message, id, timestamp tag)."""
    tags = [TAG, timestamp] if timestamp else [TAG]
    try:
        with _open(db_url) as store:
            found = next(iter(store.find_messages(topic=CLUSTER_TOPIC, tags=tags, newest_first=True,
                                                  limit=1)), None)
            if found is None:
                which = f"with timestamp {timestamp!r}" if timestamp else "at all"
                raise PersistenceError(f"no saved cluster set {which} in {_where(db_url)}")
            msg = found.message()
    except StoreError as err:
        raise PersistenceError(f"could not load clusters from {_where(db_url)}: {err}") from err
    tag = next((t for t in found.tags if t != TAG), "")
    return msg, found.id, tag
