"""Errors of the object layers (the mixture core, the layers and their queries; no rospy here).

A bad node parameter is robot_common's ConfigError (the workspace has one)."""
from robot_common.errors import NotFittedError as CommonNotFittedError
from robot_common.errors import WorkspaceError

__all__ = ["IGMMError", "NotFittedError", "InvalidInputError", "UnknownNameError", "PersistenceError"]


class IGMMError(WorkspaceError):
    """Base class of the object-layer errors."""


class NotFittedError(IGMMError, CommonNotFittedError):
    """A model is asked for something before it has seen any data."""


class InvalidInputError(IGMMError, ValueError):
    """Bad data or parameters (wrong shape, NaN, out of range); the message quotes the value."""


class UnknownNameError(IGMMError, LookupError):
    """An unknown region, layer kind, class or group name."""

    def __str__(self) -> str:  # LookupError would quote the message like a dict key
        return str(self.args[0]) if self.args else ""


class PersistenceError(IGMMError):
    """Clusters could not be saved to or loaded from the database."""
