"""ros_mongo test set-up: the shared test modules (ros_mongo_samples, recorder_harness) are
importable, and the recorder's /diagnostics watcher is a fixture."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))


@pytest.fixture
def diagnostics(rospy_node):
    """The recorder's latest /diagnostics status (recorder_harness.Diagnostics)."""
    from recorder_harness import Diagnostics

    watcher = Diagnostics()
    yield watcher
    watcher.close()
