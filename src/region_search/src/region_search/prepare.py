"""Prepare the embedding model ahead of time: train word2vec into the cache (or check the sentence
model loads), so that the embedding server's first start on a robot is a warm start.

    python -m region_search.prepare [--backend word2vec] [--cache_dir DIR] [--source auto] ...
    rosrun region_search prepare_embeddings [same options]

Every option is an embedding_server parameter (region_search.params.EmbeddingServerParams, same
names and defaults; values are read as YAML like `rosparam set`), so the model prepared is the one
the server with those parameters loads: word2vec models are cached per corpus contents +
parameters + gensim version under `cache_dir` ("" = ~/.cache/robot_ws/embeddings, or
$XDG_CACHE_HOME/robot_ws/embeddings). The default backend here is word2vec (the one that needs
preparing); `--backend sentence` checks the sentence model (and, when it cannot be loaded, prepares
its word2vec fallback). Prints the progress, the time taken and where the model is; exit status 1
with the reason when it cannot be prepared.
"""
import argparse
import sys
import time
from typing import List, Optional

import yaml

from region_search.backends import load_backend
from region_search.errors import EmbeddingError
from region_search.params import EmbeddingServerParams
from robot_common.errors import ConfigError

__all__ = ["main", "parse_config"]


def parse_config(argv: Optional[List[str]] = None) -> EmbeddingServerParams:
    """The EmbeddingServerParams of the command line (ConfigError naming a bad value)."""
    parser = argparse.ArgumentParser(
        prog="python -m region_search.prepare",
        description="Train (or check) the embedding server's model ahead of time, into its cache.")
    for name, default, doc in EmbeddingServerParams.describe():
        shown = "word2vec" if name == "backend" else default
        parser.add_argument(f"--{name}", default=None, metavar="VALUE",
                            help=f"{doc} (default: {shown!r})")
    args = parser.parse_args(argv)
    values = {"backend": "word2vec"}
    for name, value in vars(args).items():
        if value is not None:
            try:
                values[name] = yaml.safe_load(value) if value != "" else ""
            except yaml.YAMLError as err:
                raise ConfigError(f"--{name} {value!r} is not a value: {err}") from err
            if name in ("cache_dir", "model_path", "pretrained_path", "brown_path", "wordnet_dir",
                        "source", "backend"):
                values[name] = str(value)
    return EmbeddingServerParams.from_mapping(values)


def main(argv: Optional[List[str]] = None) -> int:
    try:
        config = parse_config(argv)
    except ConfigError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 2
    start = time.monotonic()
    print(f"preparing the {config.backend} embedding model (source {config.source!r}, cache "
          f"{config.cache_dir or 'default ~/.cache/robot_ws/embeddings'})", flush=True)
    try:
        loaded = load_backend(config, progress=True)
    except EmbeddingError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    info = loaded.info
    if loaded.backend == "word2vec":
        how = ("found in the cache" if info.get("cache_hit", True) else
               f"trained in {info.get('train_seconds', 0.0):.1f} s")
        print(f"word2vec {how}: {loaded.embeddings.description}; "
              f"cache {info.get('cache') or info.get('path')}")
    if loaded.note:
        print(f"NOTE: {loaded.note}")
    print(f"ready: backend {loaded.backend}, {time.monotonic() - start:.1f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
