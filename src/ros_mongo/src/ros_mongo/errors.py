"""The errors of the ros_mongo package (one base class, a few specific ones).

The recorder's error taxonomy (the same for every backend):
- *retry later* (`StoreUnavailable`): unreachable, timeouts, 5xx, 429, a write the server did not
  make durable. Everything is kept (queue, then spool) and retried with backoff.
- *operator must act* (`StoreRefused`): authentication, permission, configuration, an unsupported
  server. Kept and retried like the above; reported as an ERROR with the server's reason.
- *this document is invalid* (`DocumentsRejected`, `BatchTooLarge`): the server refused documents
  on their own merits. A batch refused as a whole (`BatchTooLarge`) is split until the offending
  document is alone; only a document refused alone is rejected (and quarantined by the recorder).
Messages of these errors never contain credentials (URLs are redacted). `StoreError` derives from
`robot_common.errors.WorkspaceError` (one root for every error the workspace raises on purpose).
"""
from typing import FrozenSet, Optional

from robot_common.errors import WorkspaceError

__all__ = ["StoreError", "StoreUnavailable", "StoreRefused", "DocumentsRejected", "BatchTooLarge",
           "QueryError", "UnknownTypeError", "BagError", "SpoolError"]


class StoreError(WorkspaceError):
    """Base class: anything that went wrong while storing or loading messages."""


class StoreUnavailable(StoreError):
    """Retry later: the server cannot be reached, timed out, is overloaded (5xx, 429) or did not
    make a write durable."""


class StoreRefused(StoreError):
    """The operator must act: credentials, permissions, configuration or server version."""


class DocumentsRejected(StoreError):
    """The server refused some documents on their own merits (the others were stored).

    Attributes: rejected (how many), rejected_ids (their message ids, where the server named them).
    """

    def __init__(self, message: str, rejected: int, rejected_ids: FrozenSet[str] = frozenset()):
        super().__init__(message)
        self.rejected = int(rejected)
        self.rejected_ids = frozenset(rejected_ids)


class BatchTooLarge(StoreError):
    """A whole batch was refused because of one document (`doc_id` when the server named it);
    nothing of the batch was stored. Split the batch and try again."""

    def __init__(self, message: str, doc_id: Optional[str] = None):
        super().__init__(message)
        self.doc_id = doc_id


class QueryError(StoreError):
    """A query is malformed: unknown key, bad operator, bad value or time range."""


class UnknownTypeError(StoreError):
    """A message type is neither installed nor described by a stored definition."""


class BagError(StoreError):
    """A bag file cannot be read or written."""


class SpoolError(StoreError):
    """The local spool file cannot be written or read."""
