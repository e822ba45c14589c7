"""Reading CouchDB in pages (no ROS): Mango `_find` has no server cursor, so a sorted stream is
read page by page (`Pager.range`), or window by window where the server filters after its index
lookup (`Pager.windows`); message id bounds for `_all_docs` ranges (`id_bound`)."""
import time
from typing import Dict, Iterator, List, Optional, Tuple

__all__ = ["Pager", "id_bound", "take"]

_MIN_WINDOW = 1e-3   # seconds: the windowed reader's smallest time window


class Pager:
    """Reads one sorted `_find` stream in pages (CouchDB has no server cursor for Mango)."""

    def __init__(self, find, base: dict, sort: list, fields: Optional[List[str]], page_size: int,
                 newest_first: bool):
        self.find, self.base, self.sort, self.fields = find, base, sort, fields
        self.page_size, self.newest_first = page_size, newest_first

    def range(self, low: Optional[float], high: Optional[float], limit: Optional[int], *,
              open_end: bool = False) -> Iterator[dict]:
        """Documents with low <= receive_time <= high (the far end excluded when `open_end`)."""
        cursor, same, yielded = None, 0, 0
        while True:
            want = self.page_size if limit is None else min(self.page_size, limit - yielded)
            if want <= 0:
                return
            body = {"selector": dict(self.base, receive_time=self._condition(low, high, cursor, open_end)),
                    "sort": self.sort, "limit": want, "skip": same}
            if self.fields:
                body["fields"] = self.fields
            docs = self.find(body)
            for doc in docs:
                if doc["receive_time"] == cursor:
                    same += 1
                else:
                    cursor, same = doc["receive_time"], 1
                yield doc
            yielded += len(docs)
            if len(docs) < want:
                return

    def _condition(self, low, high, cursor, open_end) -> Dict[str, float]:
        if cursor is not None:
            if self.newest_first:
                high = cursor
            else:
                low = cursor
        condition = {"$gte": -1e300 if low is None else low}
        if high is not None:
            condition["$lte"] = high
        if open_end and not self.newest_first and high is not None:
            condition["$lt"] = condition.pop("$lte")
        if open_end and self.newest_first and low is not None:
            condition["$gt"] = condition.pop("$gte")
        return condition

    def windows(self, bounds: Optional[Tuple[float, float]], limit: Optional[int]) -> Iterator[dict]:
        """Documents within `bounds`, read window by window; each window's span doubles while
        windows answer fast or hold few documents, and halves (down to `_MIN_WINDOW`) when they are
        slow and dense."""
        if bounds is None:
            return
        low, high = bounds
        span, yielded = 1.0, 0
        edge = high if self.newest_first else low
        while (edge >= low) if self.newest_first else (edge <= high):
            if self.newest_first:
                start, end, last = max(low, edge - span), edge, edge - span <= low
            else:
                start, end, last = edge, min(high, edge + span), edge + span >= high
            began, count = time.monotonic(), 0
            for doc in self.range(start, end, None if limit is None else limit - yielded,
                                  open_end=not last):
                yielded += 1
                count += 1
                yield doc
            if last or (limit is not None and yielded >= limit):
                return
            edge = start if self.newest_first else end
            took = time.monotonic() - began
            # A window shrinks only when it was slow because it was dense (more than a page), never
            # below a floor; a slow link with sparse windows grows them: reading always advances.
            if took > 0.5 and count > self.page_size:
                span = max(span / 2, _MIN_WINDOW)
            elif took < 0.1 or count < self.page_size // 4:
                span *= 2


def take(items: Iterator[dict], limit: int) -> Iterator[dict]:
    for count, item in enumerate(items):
        if count >= limit:
            return
        yield item


def id_bound(seconds: float, margin: int, suffix: str) -> str:
    """The message id prefix for a receive time (ids begin with the time in nanoseconds), widened
    by `margin` microseconds against rounding (the selector checks the exact time)."""
    nanoseconds = max(0, int(round(seconds * 1e9)) + margin * 1000)
    return f"{nanoseconds:019d}{suffix}"
