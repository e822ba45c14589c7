"""The loading progress the embedding server reports (region_search.progress) and the command
that prepares a model ahead of time (python -m region_search.prepare), run as a real process."""
import json
import re
import subprocess
import sys

import pytest

from region_search.prepare import parse_config
from region_search.progress import LOADING_PREFIX, PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS, LoadProgress
from robot_common.errors import ConfigError


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_progress_estimates_the_training_time_from_the_corpus_then_from_the_epochs():
    clock = Clock()
    progress = LoadProgress(clock=clock)
    progress.set_stage("reading the corpus")
    clock.now += 3
    assert progress.describe() == "reading the corpus for 3 s"
    assert progress.expected_training_seconds() is None
    progress.training_started(epochs=10, tokens=2_000_000)
    clock.now += 4
    prior = 2.0 * 10 * PRIOR_SECONDS_PER_MILLION_TOKEN_EPOCHS
    assert progress.expected_training_seconds() == pytest.approx(prior)
    assert progress.describe() == f"trained for 4 s of about {prior:.0f} s, epoch 0/10"
    clock.now += 8  # the first epoch took 12 s: 10 epochs take about 120 s
    progress.epoch_done()
    assert progress.expected_training_seconds() == pytest.approx(120.0)
    assert re.fullmatch(r"trained for 12 s of about 120 s, epoch 1/10", progress.describe())
    values = progress.snapshot()
    assert values["epochs"] == "1/10" and values["expected training [s]"] == "120"
    assert not progress.ready
    progress.training_done()
    progress.finished()
    assert progress.ready and progress.snapshot()["trained for [s]"] == "12.0"
    failed = LoadProgress(clock=clock)
    failed.finished("no WordNet at '/nowhere'")
    assert failed.describe() == "failed: no WordNet at '/nowhere'" and not failed.ready
    assert LOADING_PREFIX == "embedding model still loading"


def test_prepare_options_are_the_servers_parameters_with_word2vec_by_default():
    config = parse_config(["--cache_dir", "cache-folder", "--epochs", "3"])
    assert (config.backend, config.cache_dir, config.epochs) == ("word2vec", "cache-folder", 3)
    assert parse_config(["--backend", "sentence"]).backend == "sentence"
    with pytest.raises(ConfigError, match="epochs must be >= 1, got 0"):
        parse_config(["--epochs", "0"])


def test_prepare_command_fills_the_cache_that_the_server_then_loads(tmp_path):
    """A word2vec text file (source pretrained) is converted into the cache once; a second run
    finds it there. Real process, real files."""
    vectors = tmp_path / "vectors.txt"
    vectors.write_text("3 2\nwater 1.0 0.0\nfountain 0.9 0.1\nprinter 0.0 1.0\n")
    cache = tmp_path / "cache"
    command = [sys.executable, "-m", "region_search.prepare", "--source", "pretrained",
               "--pretrained_path", str(vectors), "--cache_dir", str(cache),
               "--remove_components", "-1"]
    first = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    assert "ready: backend word2vec" in first.stdout
    folders = list(cache.glob("pretrained-vectors.txt-*"))
    assert len(folders) == 1
    assert json.loads((folders[0] / "meta.json").read_text())["words"] == 3
    assert f"cache {folders[0]}" in first.stdout
    second = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0 and "found in the cache" in second.stdout
    bad = subprocess.run([sys.executable, "-m", "region_search.prepare", "--source",
                          "pretrained", "--pretrained_path", str(tmp_path / "missing.txt"),
                          "--cache_dir", str(cache)], capture_output=True, text=True, timeout=600)
    assert bad.returncode == 1 and "no word-vector file at" in bad.stderr
