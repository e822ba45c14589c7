"""Errors of the word-embedding service and the region recommender (no rospy here).

They derive from the package's base error `igmm_layers.errors.IGMMError`.
"""
from igmm_layers.errors import IGMMError

__all__ = ["EmbeddingError", "EmptyPhraseError", "ModelError", "CorpusError", "LabelFileError"]


class EmbeddingError(IGMMError):
    """Base class of the region-search errors (embeddings, corpora, labels)."""


class EmptyPhraseError(EmbeddingError, ValueError):
    """A phrase with no words in it (empty, blanks or punctuation only)."""


class ModelError(EmbeddingError):
    """A word-vector model cannot be trained, loaded or found."""


class CorpusError(EmbeddingError):
    """A training corpus is missing or unreadable."""


class LabelFileError(EmbeddingError):
    """A map_labelling label file is missing or malformed."""
