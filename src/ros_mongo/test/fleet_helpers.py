"""What the fleet tests share: central's documents read back, and a robot's publisher and
processes (each test's robot class adds how it records)."""
import json
import sys
from pathlib import Path

import requests

from ros_harness import ManagedProcess

HERE = Path(__file__).resolve().parent


def all_docs(db_url):
    """Every document of a database (attachment stubs only), with `_conflicts` where any."""
    docs, start = [], None
    while True:
        params = {"include_docs": "true", "conflicts": "true", "limit": "501"}
        if start is not None:
            params["startkey"] = json.dumps(start)
        rows = requests.get(db_url + "/_all_docs", params=params, timeout=60).json()["rows"]
        docs += [row["doc"] for row in rows[:500]]
        if len(rows) <= 500:
            return docs
        start = rows[500]["id"]


def holds(db_url, count) -> bool:
    """Whether the database holds at least `count` documents (its doc_count: one small request).
    It holds at least as many documents as messages, so a wait for `count` messages reads them
    all (`all_docs`, tens of milliseconds of the server's and this process's CPU a poll) only
    once this is true."""
    try:
        return requests.get(db_url, timeout=30).json()["doc_count"] >= count
    except (requests.RequestException, ValueError, KeyError):
        return False


def messages(docs):
    return [d for d in docs if d.get("kind") == "message"]


def content(doc):
    """What a message is, read from its stored fields: (robot, topic, index sent in frame_id)."""
    return doc["robot_id"], doc["topic"], int(doc["msg"]["header"]["frame_id"])


class FleetRobot:
    """A robot's fleet test publisher (fleet_publisher.py on the robot's roscore) and clean-up;
    subclasses set robot_id, work, core and launches."""

    publisher = None

    def publish(self, count, rate, hold_at):
        self.go_file = self.work / "go"
        self.publisher = ManagedProcess(
            [sys.executable, str(HERE / "fleet_publisher.py"), "--count", count, "--rate", rate,
             "--hold-at", hold_at, "--go-file", self.go_file],
            name=f"publisher {self.robot_id}", log_path=self.work / "publisher.log",
            env=self.core.env()).start()

    def published(self):
        for line in self.publisher.log_path.read_text().splitlines():
            if line.startswith("{"):
                return json.loads(line)["published"]
        raise AssertionError(f"no counts from the publisher: {self.publisher.log_tail()}")

    def close(self):
        if self.publisher is not None:
            self.publisher.stop()
        self.launches.stop_all()
        self.core.stop()
