"""The upload ledger (no ROS): per topic, what the robot recorded, uploaded, holds and dropped,
kept in `<spool_path>.ledger` (JSON, replaced atomically) so it survives restarts.

Each recorder adds its own counts to what the file held when it started (`base`) and saves the
sum every few seconds and when it stops. `waiting` (messages on the robot's disk only) is read
from the spool when the ledger is saved. A recorder killed between two saves loses its last
seconds of counts (never messages: those are in the spool or on central; a batch drained again
after such a kill is counted as uploaded again).
"""
import json
import logging
import os
from pathlib import Path
from typing import Dict, Mapping, Union

from ros_mongo.errors import SpoolError

__all__ = ["Ledger", "LEDGER_FIELDS", "format_ledger", "read_ledger"]

log = logging.getLogger(__name__)

#: Counted fields per topic (summed over recorder runs); "waiting" and "reason" are the latest.
LEDGER_FIELDS = ("recorded", "uploaded", "dropped", "recycled")


class Ledger:
    """The ledger file of a spool and the counts it held at start."""

    def __init__(self, path: Union[str, Path]):
        self.path = Path(path)
        self.base: Dict[str, Dict[str, object]] = {}

    def load(self) -> "Ledger":
        """Read the counts of earlier runs (none when the file is missing)."""
        if self.path.exists():
            self.base = read_ledger(self.path)
        return self

    def combine(self, counts: Mapping[str, Mapping[str, int]], waiting: Mapping[str, int],
                reasons: Mapping[str, str]) -> Dict[str, Dict[str, object]]:
        """The ledger now: `counts` ({field: {topic: n}} of this run) added to `base`, `waiting`
        and the latest drop reason per topic."""
        topics = set(self.base) | set(waiting) | {t for per in counts.values() for t in per}
        ledger: Dict[str, Dict[str, object]] = {}
        for topic in sorted(topics):
            old = self.base.get(topic, {})
            row: Dict[str, object] = {f: int(old.get(f, 0)) + int(counts.get(f, {}).get(topic, 0))
                                      for f in LEDGER_FIELDS}
            row["waiting"] = int(waiting.get(topic, 0))
            reason = reasons.get(topic) or old.get("reason", "")
            if reason:
                row["reason"] = reason
            ledger[topic] = row
        return ledger

    def save(self, ledger: Mapping[str, Mapping[str, object]]) -> None:
        temporary = Path(str(self.path) + ".tmp")
        try:
            temporary.write_text(json.dumps({"topics": ledger}, indent=1, sort_keys=True))
            os.replace(temporary, self.path)
        except OSError as err:
            raise SpoolError(f"cannot write the ledger {self.path}: {err}") from err


def read_ledger(path: Union[str, Path]) -> Dict[str, Dict[str, object]]:
    """The per-topic rows of a ledger file (SpoolError naming the file when it is unreadable)."""
    try:
        data = json.loads(Path(path).read_text())
        topics = data["topics"]
        if not isinstance(topics, dict):
            raise TypeError("'topics' is not a mapping")
        return {str(topic): dict(row) for topic, row in topics.items()}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise SpoolError(f"cannot read the ledger {path}: {err}") from err


def format_ledger(ledger: Mapping[str, Mapping[str, object]]) -> str:
    """A table of the ledger, one line per topic."""
    columns = LEDGER_FIELDS + ("waiting",)
    width = max([len("topic")] + [len(t) for t in ledger])
    lines = [f"{'topic':<{width}}  " + "  ".join(f"{c:>9}" for c in columns) + "  reason"]
    for topic, row in sorted(ledger.items()):
        lines.append(f"{topic:<{width}}  " + "  ".join(f"{int(row.get(c, 0)):>9}" for c in columns)
                     + f"  {row.get('reason', '')}")
    return "\n".join(lines)
