"""Markers of the region_search tests: `@pytest.mark.wordnet` skips a test when Debian's
wordnet-base is not installed. The shared test module (region_search_never_hurt) is importable."""
import sys
from pathlib import Path

import pytest

from region_search.corpora import DEFAULT_WORDNET_DIR

WORDNET = Path(DEFAULT_WORDNET_DIR)

sys.path.insert(0, str(Path(__file__).resolve().parent))


def pytest_configure(config):
    config.addinivalue_line("markers", "wordnet: needs Debian's wordnet-base (scripts/setup.sh)")


def pytest_runtest_setup(item):
    if item.get_closest_marker("wordnet") and not (WORDNET / "data.noun").is_file():
        pytest.skip("Debian's wordnet-base is not installed (scripts/setup.sh)")
