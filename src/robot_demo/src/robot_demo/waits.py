"""Waits of the demo that say what they wait for, their bound, and how long they took.

Every bound is a few times what a quiet 2-core machine needs, so that it holds on a machine twice
as slow (or with both cores busy); a wait that runs out raises TimeoutError naming what it waited
for. `DEMO_BOUND_SCALE` (a number, default 1) scales every bound for a machine slower still.
"""
import os
import time
from typing import Callable, Iterable

import ros_harness

__all__ = ["bound", "wait_until", "services", "topics", "subscribers", "message"]


def bound(seconds: float) -> float:
    """A wait's bound in seconds, scaled by DEMO_BOUND_SCALE."""
    try:
        scale = float(os.environ.get("DEMO_BOUND_SCALE", "1"))
    except ValueError:
        scale = 1.0
    return seconds * max(scale, 1.0)


def _waiting(what: str, limit: float, wait: Callable[[], object]):
    print(f"    waiting for {what} (at most {limit:.0f} s) ...", end="", flush=True)
    start = time.monotonic()
    try:
        value = wait()
    except BaseException:
        print(f" not within {time.monotonic() - start:.1f} s", flush=True)
        raise
    print(f" {time.monotonic() - start:.1f} s", flush=True)
    return value


def wait_until(condition: Callable[[], object], seconds: float, what: str, **kwargs):
    """`ros_harness.wait_until` with the wait and its bound printed; returns the condition's value."""
    limit = bound(seconds)
    return _waiting(what, limit,
                    lambda: ros_harness.wait_until(condition, limit, what=what, **kwargs))


def services(launch, names: Iterable[str], seconds: float) -> None:
    """Wait until a launch's services are advertised."""
    names = list(names)
    limit = bound(seconds)
    _waiting(f"services {', '.join(names)}", limit,
             lambda: launch.wait_for_services(names, timeout=limit))


def topics(launch, names: Iterable[str], seconds: float) -> None:
    """Wait until a launch's topics are published."""
    names = list(names)
    limit = bound(seconds)
    _waiting(f"topics {', '.join(names)}", limit, lambda: launch.wait_for_topics(names, timeout=limit))


def subscribers(launch, names: Iterable[str], seconds: float) -> None:
    """Wait until a launch's nodes subscribe to the topics."""
    names = list(names)
    limit = bound(seconds)
    _waiting(f"subscribers of {', '.join(names)}", limit,
             lambda: launch.wait_for_subscribers(names, timeout=limit))


def message(topic: str, kind, seconds: float):
    """The next message on a topic (the latched one at once), with the wait printed."""
    import rospy

    limit = bound(seconds)
    return _waiting(f"a message on {topic}", limit,
                    lambda: rospy.wait_for_message(topic, kind, limit))
