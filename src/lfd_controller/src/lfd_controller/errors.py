"""Errors of the lfd_controller package."""


class LfdError(RuntimeError):
    """Base error of learning from demonstration."""


class DemonstrationError(LfdError):
    """A demonstration is missing, malformed or inconsistent with its scenario."""


class LearningError(LfdError):
    """Inverse optimal control could not learn a reward from the given demonstrations."""


class NotFittedError(LfdError):
    """A reward or policy was used before it was learned or loaded."""


class RewardFileError(LfdError):
    """A saved reward file is missing or malformed."""
