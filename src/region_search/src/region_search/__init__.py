"""Region search: phrases ("drinking fountain") to the labelled places of a map they mean.

Pure-Python cores (no rospy): word and phrase vectors (embeddings, sentence, training, backends),
corpora (Brown, WordNet), label matching (recommender: word by word; phrase: phrase vectors),
the nodes' parameters (node_config). The ROS nodes are in ros_region_search.py and nodes/.
"""
from region_search.errors import CorpusError, EmbeddingError, EmptyPhraseError, LabelFileError, ModelError
from region_search.node_config import BackendConfig, RegionRecommenderConfig
from region_search.phrase import PhraseRegionRecommender
from region_search.recommender import Recommendation, Region, RegionRecommender

__all__ = [
    "BackendConfig",
    "RegionRecommenderConfig",
    "Region",
    "RegionRecommender",
    "PhraseRegionRecommender",
    "Recommendation",
    "EmbeddingError",
    "EmptyPhraseError",
    "ModelError",
    "CorpusError",
    "LabelFileError",
]
