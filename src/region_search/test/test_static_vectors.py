"""The static phrase vectors (region_search.static_vectors): the wheel's weights load only when
they are the expected file, and phrases get unit vectors that rank by meaning."""
import numpy as np
import pytest

from region_search.errors import ModelError
from region_search.static_vectors import WEIGHTS, load_static_model, package_dir, read_safetensors


def test_phrases_get_unit_vectors_and_words_outside_the_vocabulary_are_reported():
    model = load_static_model(cache_size=10)
    assert model.backend == "static" and model.dimension == 256
    embedded = model.embed_phrases(["drinking fountain", "water fountain", "elevator"])
    assert np.allclose(np.linalg.norm(embedded.vectors, axis=1), 1.0, atol=1e-5)
    drinking, water, elevator = embedded.vectors
    assert drinking @ water > drinking @ elevator
    typo = model.embed_phrases(["the printerz room"])
    assert typo.oov == ["printerz"] and "printerz: not a whole word" in typo.notes[0]


def test_weights_that_are_not_the_pinned_file_are_refused(tmp_path):
    weights = (package_dir() / WEIGHTS).read_bytes()
    changed = tmp_path / "weights.safetensors"
    changed.write_bytes(weights[:-1] + bytes([weights[-1] ^ 1]))  # one bit of the last value
    with pytest.raises(ModelError, match="SHA-256 differs"):
        read_safetensors(changed)
    assert read_safetensors(changed, sha256="").shape == (32000, 256)  # unchecked: it reads
    (tmp_path / "not.safetensors").write_bytes(b"\x02\x00\x00\x00\x00\x00\x00\x00{}")
    with pytest.raises(ModelError, match="is not a safetensors file with 'embedding.weight'"):
        read_safetensors(tmp_path / "not.safetensors", sha256="")
