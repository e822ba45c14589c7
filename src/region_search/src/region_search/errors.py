"""Errors of region search: the embedding models, the corpora and the region recommender
(no rospy here).

`EmbeddingError` is the package's base error (a `robot_common.errors.WorkspaceError`); service
handlers turn it into `success=False` and a message, the node executables into one FATAL line and
exit status 1. Bad node parameters raise `robot_common.errors.ConfigError`.
"""
from robot_common.errors import WorkspaceError

__all__ = ["EmbeddingError", "EmptyPhraseError", "ModelError", "CorpusError", "LabelFileError",
           "EmbeddingUnavailableError", "ModelLoadingError"]


class EmbeddingError(WorkspaceError):
    """Base class of the region-search errors (embeddings, corpora, labels)."""


class EmptyPhraseError(EmbeddingError, ValueError):
    """A phrase with no words in it (empty, blanks or punctuation only)."""


class ModelError(EmbeddingError):
    """A word-vector model cannot be trained, loaded or found."""


class CorpusError(EmbeddingError):
    """A training corpus is missing or unreadable."""


class LabelFileError(EmbeddingError):
    """A map_labelling label file is missing or malformed."""


class EmbeddingUnavailableError(EmbeddingError):
    """The embedding service cannot be reached (not advertised yet, or its server went away)."""


class ModelLoadingError(EmbeddingError):
    """The embedding server is up but its model is still loading (or training)."""
