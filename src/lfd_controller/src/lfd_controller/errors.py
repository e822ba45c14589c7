"""Errors of the lfd_controller package (all derive from robot_common.errors.WorkspaceError; a bad
node parameter is robot_common.errors.ConfigError)."""
from robot_common.errors import NotFittedError as CommonNotFittedError
from robot_common.errors import WorkspaceError


class LfdError(WorkspaceError, RuntimeError):
    """Base error of learning from demonstration."""


class DemonstrationError(LfdError):
    """A demonstration is missing, malformed or inconsistent with its scenario."""


class LearningError(LfdError):
    """Inverse optimal control could not learn a reward from the given demonstrations."""


class NotFittedError(LfdError, CommonNotFittedError):
    """A reward or policy was used before it was learned or loaded."""


class RewardFileError(LfdError):
    """A saved reward file is missing or malformed."""
