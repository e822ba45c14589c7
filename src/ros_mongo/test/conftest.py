"""ros_mongo test set-up: the shared message builders (ros_mongo_samples) are importable."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
