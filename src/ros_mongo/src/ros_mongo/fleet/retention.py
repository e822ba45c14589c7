"""Local retention on a robot: delete what the central server provably holds (no ROS here).

Contract: a message document of the robot's store is deleted only when
- it is selected for replication (`ReplicationSpec.selects`: local-only topics are never deleted
  by this rule, since they never go up),
- its `receive_time` (seconds since the epoch, the robot's clock) is older than `older_than`
  seconds before now (documents without a numeric `receive_time` are kept), and
- the central database answered `_revs_diff` saying it holds that very `_id` and `_rev` (the
  replication writes a revision with its attachments in one step, so the attachment is there too).
Topic documents and design documents are never deleted. A document changed between the check and
the delete is kept (the delete conflicts) and looked at again in a later pass. Any error of either
server ends the pass with nothing more deleted (ReplicationError subclasses; see
ros_mongo.fleet.replication).

The delete leaves a tombstone (pouchdb-server has no `_purge`). Tombstones never reach the
central database: the replication's selector needs `kind`, which a tombstone lacks. The disk
space comes back when the store compacts (`compact=True` asks for `POST /db/_compact` after a pass
that deleted something).

A pass reads at most `max_docs` documents in `_id` order from where the previous pass stopped
(wrapping around at the end), so a large store is covered over several passes without long pauses.
"""
import logging
import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional

from ros_mongo.fleet.replication import CouchDatabase, ReplicationError, ReplicationSpec

__all__ = ["RetentionResult", "Retention"]

logger = logging.getLogger(__name__)


@dataclass
class RetentionResult:
    """One pass: documents read, deleted, and old-enough ones kept because central lacks them."""

    examined: int = 0
    deleted: int = 0
    kept_unconfirmed: int = 0
    wrapped: bool = False


class Retention:
    """Deletes old, centrally confirmed message documents from the robot's store (see module)."""

    def __init__(self, local: CouchDatabase, central: CouchDatabase, spec: ReplicationSpec, *,
                 older_than: float, max_docs: int = 5000, page: int = 500, compact: bool = True,
                 clock: Callable[[], float] = time.time):
        if not older_than > 0:
            raise ReplicationError(f"retention age must be > 0 seconds: got {older_than!r}")
        if max_docs < 1 or page < 1:
            raise ReplicationError(f"max_docs and page must be >= 1: got {max_docs}, {page}")
        self.local = local
        self.central = central
        self.spec = spec
        self.older_than = float(older_than)
        self.max_docs = max_docs
        self.page = page
        self.compact = compact
        self.clock = clock
        self._next_key: Optional[str] = None
        self.total_deleted = 0

    def _candidates(self, rows: List[dict], cutoff: float) -> Dict[str, str]:
        found = {}
        for row in rows:
            doc = row.get("doc") or {}
            if doc.get("kind") not in ("message", "chunk") or not self.spec.selects(doc):
                continue
            stamp = doc.get("receive_time")
            if isinstance(stamp, (int, float)) and not isinstance(stamp, bool) and stamp < cutoff:
                found[row["id"]] = doc["_rev"]
        return found

    def _delete(self, revs: Dict[str, str]) -> int:
        docs = [{"_id": i, "_rev": r, "_deleted": True} for i, r in revs.items()]
        answer = self.local.json("POST", "/_bulk_docs", json={"docs": docs})
        return sum(1 for item in answer if "error" not in item)

    def run_once(self) -> RetentionResult:
        """One bounded pass (see the module docstring)."""
        result = RetentionResult()
        cutoff = self.clock() - self.older_than
        while result.examined < self.max_docs:
            params = {"include_docs": "true", "limit": str(self.page + 1)}
            if self._next_key is not None:
                params["startkey"] = '"' + self._next_key.replace("\\", "\\\\").replace('"', '\\"') + '"'
            rows = self.local.json("GET", "/_all_docs", params=params).get("rows", [])
            page_rows, more = rows[:self.page], rows[self.page:]
            result.examined += len(page_rows)
            candidates = self._candidates(page_rows, cutoff)
            if candidates:
                missing = self.central.revs_missing(candidates)
                confirmed = {i: r for i, r in candidates.items() if i not in missing}
                result.kept_unconfirmed += len(candidates) - len(confirmed)
                if confirmed:
                    result.deleted += self._delete(confirmed)
            if not more:
                self._next_key = None
                result.wrapped = True
                break
            self._next_key = more[0]["id"]
        self.total_deleted += result.deleted
        if result.deleted and self.compact:
            self.local.request("POST", "/_compact", json={}, ok=(200, 201, 202))
        if result.deleted or result.kept_unconfirmed:
            logger.info("retention: deleted %d documents held centrally, kept %d old ones not "
                        "confirmed central yet", result.deleted, result.kept_unconfirmed)
        return result
