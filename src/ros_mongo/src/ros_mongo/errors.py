"""The errors of the ros_mongo package (one base class, a few specific ones)."""

__all__ = ["StoreError", "StoreUnavailable", "QueryError", "UnknownTypeError", "BagError", "SpoolError"]


class StoreError(Exception):
    """Base class: anything that went wrong while storing or loading messages."""


class StoreUnavailable(StoreError):
    """The database server cannot be reached (connection refused, timed out, DNS...)."""


class QueryError(StoreError):
    """A query is malformed: unknown key, bad operator, bad value or time range."""


class UnknownTypeError(StoreError):
    """A message type is neither installed nor described by a stored definition."""


class BagError(StoreError):
    """A bag file cannot be read or written."""


class SpoolError(StoreError):
    """The local spool file cannot be written or read."""
