"""What the drivers' reader threads hand to the mapper thread without waiting: recent odometry and
the pose at any time (:class:`OdometryBuffer`), a bounded queue that drops its oldest item
(:class:`DropOldest`), and an event rate (:class:`Rate`). Times are ``time.monotonic()`` seconds of
this host; odometry is in the odometry frame (m, rad)."""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from typing import Any

from mapper.se2 import Pose, compose, interpolate, inverse


class OdometryBuffer:
    """Recent odometry (t s, x, y m, theta rad; odometry frame) and the pose at any time.

    :meth:`at` interpolates between the samples around ``t``; past the newest sample it
    extrapolates at the last measured velocity for at most ``max_extrapolation`` seconds (a scan
    usually ends between two SIPs; waiting for the next SIP would add up to 100 ms of latency).
    That velocity is measured over at least ``velocity_baseline`` seconds (from the newest sample back
    to the newest one that much older): SIPs completed by one late read arrive milliseconds apart,
    and a velocity taken between two of them would throw the extrapolated pose metres away.

    Odometry restarts at (0, 0, 0) whenever P2OS is reopened; :meth:`new_session` makes the next
    sample continue from the last pose so the mapper sees one continuous odometry frame.
    """

    def __init__(self, history: float = 5.0, max_extrapolation: float = 0.25,
                 velocity_baseline: float = 0.05):
        self.history = history
        self.max_extrapolation = max_extrapolation
        self.velocity_baseline = velocity_baseline
        self._t: list[float] = []
        self._p: list[Pose] = []
        self._offset: Pose = (0.0, 0.0, 0.0)
        self._rebase = False
        self._lock = threading.Lock()

    def new_session(self) -> None:
        """The next sample starts a new odometry session (the driver was reopened)."""
        with self._lock:
            self._rebase = True

    def add(self, t: float, x: float, y: float, theta: float) -> Pose:
        """Record a raw sample; returns it in the continuous frame. Samples going back in time are
        ignored (a reordered callback must not bend the trajectory)."""
        with self._lock:
            raw = (float(x), float(y), float(theta))
            if self._rebase and self._p:
                self._offset = compose(self._p[-1], inverse(raw))
            self._rebase = False
            pose = compose(self._offset, raw)
            if self._t and t <= self._t[-1]:
                return pose
            self._t.append(float(t))
            self._p.append(pose)
            if self._t[0] < t - self.history and len(self._t) > 2:
                cut = bisect.bisect_left(self._t, t - self.history)
                del self._t[: min(cut, len(self._t) - 2)], self._p[: min(cut, len(self._p) - 2)]
            return pose

    def latest(self) -> tuple[float, Pose] | None:
        with self._lock:
            return (self._t[-1], self._p[-1]) if self._t else None

    def at(self, t: float) -> Pose | None:
        """The pose at time ``t`` (s), or None before any odometry."""
        with self._lock:
            n = len(self._t)
            if n == 0:
                return None
            if n == 1 or t <= self._t[0]:
                return self._p[0] if t <= self._t[0] else self._p[-1]
            i = bisect.bisect_left(self._t, t)
            if i >= n:  # after the newest sample: extrapolate over the velocity baseline
                t1 = self._t[-1]
                t = min(t, t1 + self.max_extrapolation)
                j = max(0, min(bisect.bisect_right(self._t, t1 - self.velocity_baseline) - 1, n - 2))
                return interpolate(self._p[j], self._p[-1], (t - self._t[j]) / (t1 - self._t[j]))
            t0, t1 = self._t[i - 1], self._t[i]
            return interpolate(self._p[i - 1], self._p[i], (t - t0) / (t1 - t0))


class DropOldest:
    """A bounded FIFO between a producer that must never wait and a slower consumer."""

    def __init__(self, maxlen: int):
        self._d: deque = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, item: Any) -> None:
        with self._cond:
            if len(self._d) >= self._maxlen:
                self._d.popleft()
                self.dropped += 1
            self._d.append(item)
            self._cond.notify()

    def get(self, timeout: float) -> Any | None:
        with self._cond:
            if not self._d:
                self._cond.wait(timeout)
            return self._d.popleft() if self._d else None

    def __len__(self) -> int:
        return len(self._d)


class Rate:
    """Events per second over the last ``window`` seconds."""

    def __init__(self, window: float = 2.0):
        self._times: deque[float] = deque()
        self.window = window

    def tick(self, now: float | None = None) -> None:
        self._times.append(time.monotonic() if now is None else now)

    def hz(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        while self._times and self._times[0] < now - self.window:
            self._times.popleft()
        return len(self._times) / self.window
