"""The upload bandwidth cap of a recorder (no ROS): one token bucket shared by every upload, by
priority.

`rate` bytes per second, bursts of up to one second's worth. A *live* write (the queue's batches and
the spool of live topics drained after an outage) waits only while the bucket is in debt, then
takes its bytes (possibly into debt): live topics are never held back by deferred data, and their
long-run rate is the cap. A *deferred* write (a released `upload: when` part) waits until the
bucket holds its bytes (up to one burst) and no live write is waiting: it gets what live topics
leave. The recorder takes the bytes of the encoded documents (base64 bytes, decoded fields,
document keys: the request bodies), just before it sends them.
"""
import threading
import time
from typing import Callable, Optional

from ros_mongo.errors import StoreUnavailable

__all__ = ["Bandwidth"]

class Bandwidth:
    """The token bucket (see the module docstring); rate 0 or less: no cap.

    Args:
        rate: bytes per second.
        clock, wait: the monotonic clock and how a waiting writer sleeps (replaceable in tests;
            default time.monotonic and the bucket's condition variable).
    """

    def __init__(self, rate: float, *, clock: Callable[[], float] = time.monotonic,
                 wait: Optional[Callable[[float], object]] = None):
        self.rate = float(rate)
        self.burst = max(self.rate, 1.0)
        self._clock = clock
        self._cond = threading.Condition()
        self._wait = wait or self._cond.wait
        self._tokens, self._stamp = self.burst, clock()
        self._live_waiting = 0
        self.waited = 0.0  # seconds writers spent waiting for the cap

    @property
    def active(self) -> bool:
        return self.rate > 0

    def take(self, nbytes: int, *, live: bool = True, deadline: float = float("inf")) -> None:
        """Wait for the cap, then take `nbytes`; StoreUnavailable when `deadline` (monotonic)
        passes first (the caller keeps the data in its spool)."""
        if not self.active:
            return
        with self._cond:
            self._live_waiting += live
            try:
                started = self._clock()
                while not self._ready(nbytes, live):
                    now = self._clock()
                    if now >= deadline:
                        raise StoreUnavailable("the upload bandwidth cap left no time before stopping")
                    short = -self._tokens if live else min(nbytes, self.burst) - self._tokens
                    self._wait(min(max(short / self.rate, 0.001), 0.5, max(deadline - now, 0.001)))
                self._tokens -= nbytes
                self.waited += self._clock() - started
            finally:
                self._live_waiting -= live
                self._cond.notify_all()

    def _ready(self, nbytes: int, live: bool) -> bool:
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._stamp) * self.rate)
        self._stamp = now
        if live:
            return self._tokens >= 0
        return self._live_waiting == 0 and self._tokens >= min(nbytes, self.burst)
