"""Region search: phrases ("drinking fountain") to the labelled places of a map they mean.

Pure-Python cores (no rospy): word and phrase vectors (embeddings, sentence, static_vectors,
training, backends), corpora (Brown, WordNet), place knowledge from WordNet (knowledge), label
matching (recommender: word by word; phrase: phrase vectors), the ranking that weighs the
evidence and says when no place matches (ranking), the nodes' parameters (params). The ROS
nodes are in ros_embedding_server.py, ros_region_recommender.py and nodes/.
"""
from region_search.errors import CorpusError, EmbeddingError, EmptyPhraseError, LabelFileError, ModelError
from region_search.params import EmbeddingServerParams, RegionRecommenderParams
from region_search.phrase import PhraseRegionRecommender
from region_search.ranking import (
    PlaceRecommender,
    RankingWeights,
    SentenceFeatures,
    WordFeatures,
    load_ranking_weights,
)
from region_search.recommender import Recommendation, Region, RegionRecommender

__all__ = [
    "EmbeddingServerParams",
    "RegionRecommenderParams",
    "Region",
    "PlaceRecommender",
    "RankingWeights",
    "SentenceFeatures",
    "WordFeatures",
    "load_ranking_weights",
    "RegionRecommender",
    "PhraseRegionRecommender",
    "Recommendation",
    "EmbeddingError",
    "EmptyPhraseError",
    "ModelError",
    "CorpusError",
    "LabelFileError",
]
