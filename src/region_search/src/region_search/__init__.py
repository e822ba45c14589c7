"""Region search: phrases ("drinking fountain") to the labelled places of a map they mean.

Pure-Python cores (no rospy): word and phrase vectors (embeddings, sentence, static_vectors,
training, backends), corpora (Brown, WordNet), place knowledge from WordNet (knowledge), labelled
places and answers (labels), word-by-word matching (word_matching), the ranking that weighs the
evidence and says when no place matches (ranking, ranking_settings), the nodes' parameters
(params). The ROS nodes are in ros_embedding_server.py, ros_region_recommender.py and nodes/.
"""
from region_search.errors import CorpusError, EmbeddingError, EmptyPhraseError, LabelFileError, ModelError
from region_search.labels import Recommendation, Region
from region_search.params import EmbeddingServerParams, RegionRecommenderParams
from region_search.ranking import (
    PlaceRecommender,
    RankingWeights,
    SentenceFeatures,
    WordFeatures,
    load_ranking_weights,
)
from region_search.word_matching import WordMatcher

__all__ = [
    "EmbeddingServerParams",
    "RegionRecommenderParams",
    "Region",
    "PlaceRecommender",
    "RankingWeights",
    "SentenceFeatures",
    "WordFeatures",
    "load_ranking_weights",
    "WordMatcher",
    "Recommendation",
    "EmbeddingError",
    "EmptyPhraseError",
    "ModelError",
    "CorpusError",
    "LabelFileError",
]
