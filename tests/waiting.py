"""Waiting on wall-clock conditions in tests of threaded devices (emulators, drivers)."""

from __future__ import annotations

import time
from collections.abc import Callable


def until(cond: Callable[[], bool], timeout: float = 2.0, step: float = 0.01,
          wait: Callable[[float], object] = time.sleep) -> bool:
    """Whether ``cond()`` became true within ``timeout`` (s), checked every ``step`` (s) of
    ``wait(step)``: ``time.sleep`` by default, or a call that drains a serial line meanwhile."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        wait(step)
    return bool(cond())
