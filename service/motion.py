"""Motion only while its source is fresh: the service's last line against a runaway robot.

P2OS keeps driving at the last setpoint for as long as the host keeps its 2 s watchdog fed, and the
driver feeds it with PULSEs whatever the rest of the service is doing. So a velocity source that
hangs (the mapper thread wedged mid-exploration, a Zenoh client that vanished) would leave the robot
driving blind. :class:`MotionGate` passes velocity commands to the robot and, on its own thread,
commands zero velocity once no new command came for ``max_age`` seconds (``time.monotonic()``).

:func:`stop_on_thread_crash` installs a ``threading.excepthook`` that stops the robot when any
thread dies of an exception, before the usual report.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class MotionGate:
    """Velocity commands to ``send(v, w)`` (m/s, rad/s; robot frame: x forward, w counter-clockwise)
    that expire: ``max_age`` s after the last :meth:`command` the gate calls ``halt()`` (zero
    velocity) once, from its watch thread polling every ``poll`` s. Every stop has a reason,
    kept in :attr:`last_stop` (time, reason) for the status."""

    def __init__(self, send: Callable[[float, float], Any], halt: Callable[[], Any], max_age: float = 0.5,
                 poll: float = 0.05):
        self._send = send
        self._halt = halt
        self.max_age = max_age
        self.poll = poll
        self.last_stop: tuple[float, str] | None = None
        self.expired = 0
        self._source = ""
        self._last = 0.0
        self._moving = False
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="motion-gate", daemon=True)

    def start(self) -> MotionGate:
        self._thread.start()
        return self

    def command(self, v: float, w: float, source: str) -> Any:
        """Send ``v``, ``w`` now on behalf of ``source`` ("explore"); it lasts ``max_age`` s unless
        renewed. Whatever ``send`` raises reaches the caller."""
        with self._lock:
            self._source, self._last = source, time.monotonic()
            result = self._send(v, w)
            self._moving = v != 0.0 or w != 0.0
            return result

    def stop(self, reason: str) -> bool:
        """Zero velocity now; True when the robot took the command."""
        with self._lock:
            return self._stop(reason)

    def _stop(self, reason: str) -> bool:
        self._moving = False
        self.last_stop = (time.monotonic(), reason)
        try:
            ok = self._halt()
        except Exception as exc:  # a lost link: P2OS's own watchdog stops the motors within 2 s
            log.warning("could not stop the robot (%s): %s", reason, exc)
            return False
        return ok is not False

    def check(self, now: float | None = None) -> bool:
        """Stop the robot if its last motion command is older than ``max_age``; True if it did."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if not self._moving or now - self._last <= self.max_age:
                return False
            self.expired += 1
            why = f"no motion command from {self._source or 'any source'} for {now - self._last:.2f} s"
            log.warning("stopping the robot: %s", why)
            self._stop(why)
            return True

    def _watch(self) -> None:
        try:
            while not self._closing.wait(self.poll):
                self.check()
        finally:  # however this thread ends, the robot is left stopped
            if self._moving:
                with self._lock:
                    self._stop("the motion gate stopped")

    def close(self, reason: str = "shutting down") -> None:
        """Stop watching, and stop the robot."""
        self._closing.set()
        if self._thread.ident is not None:
            self._thread.join(1.0)
        self.stop(reason)


def stop_on_thread_crash(stop: Callable[[str], Any]) -> Callable[[], None]:
    """Install a ``threading.excepthook`` that calls ``stop(reason)`` when any thread dies of an
    exception, then reports it as before. Returns a function that restores the previous hook."""
    previous = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        if args.exc_type is not SystemExit:
            name = args.thread.name if args.thread is not None else "?"
            try:
                stop(f"thread {name} died: {args.exc_type.__name__}: {args.exc_value}")
            except Exception:
                log.exception("stopping the robot after a thread crash failed")
        previous(args)

    threading.excepthook = hook

    def restore() -> None:
        if threading.excepthook is hook:
            threading.excepthook = previous

    return restore
