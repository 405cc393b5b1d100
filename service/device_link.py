"""One serial device kept open (:class:`Link`): opened on its own thread, watched for silence,
reported at ``fault`` and ``recovered``, and reopened without restarting the service."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from service.buffers import Rate

log = logging.getLogger(__name__)


class Link:
    """Keeps one device open: ``open_device()`` builds the driver, ``attach(device)`` hooks its
    callbacks (which call :meth:`touch`). No data for ``stale_after`` seconds (or an open that
    fails) is a fault: the device is closed and reopened after ``retry`` seconds, doubling after
    each failed open up to 2 s, until it answers.

    ``on_change(name, state, reason)`` runs on this link's thread at ``fault`` and at ``recovered``;
    states: ``connecting`` (never up yet), ``ok``, ``fault``.
    """

    def __init__(self, name: str, open_device: Callable[[], Any], attach: Callable[[Any], None],
                 stale_after: float, retry: float, on_change: Callable[[str, str, str], None]):
        self.name = name
        self._open = open_device
        self._attach = attach
        self.stale_after = stale_after
        self.retry = retry
        self._on_change = on_change
        self.state = "connecting"
        self.reason = ""
        self.faults = 0
        self.recoveries = 0
        self.device: Any = None
        self.rate = Rate()
        self._last = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"link-{name}", daemon=True)

    def start(self) -> Link:
        self._thread.start()
        return self

    def touch(self, device: Any) -> bool:
        """Data arrived from ``device``; False if it is not the current device (a stale callback)."""
        if device is not self.device:
            return False
        self._last = time.monotonic()
        self.rate.tick(self._last)
        return True

    def _set(self, state: str, reason: str) -> None:
        before, self.state, self.reason = self.state, state, reason
        if state == "fault" and before != "fault":
            self.faults += 1
            log.warning("%s: fault: %s", self.name, reason)
            self._on_change(self.name, "fault", reason)
        elif state == "ok" and before == "fault":
            self.recoveries += 1
            log.warning("%s: recovered", self.name)
            self._on_change(self.name, "recovered", "")
        elif state == "ok":
            log.info("%s: connected", self.name)

    def _run(self) -> None:
        failures = 0
        while not self._stop.is_set():
            try:
                dev = self._open()
            except Exception as exc:  # every failure to open is a fault to report, then retry
                self._set("fault", f"cannot open: {exc}")
                # Back off (doubling, at most 2 s): a device that is gone for minutes is not
                # hammered, and one that returns is found again within 2 s.
                self._stop.wait(min(self.retry * 2 ** failures, max(self.retry, 2.0)))
                failures += 1
                continue
            failures = 0
            self._last = time.monotonic()
            self.device = dev
            try:
                self._attach(dev)
                self._set("ok", "")
                while not self._stop.wait(0.02):
                    silent = time.monotonic() - self._last
                    if silent > self.stale_after:
                        self._set("fault", f"no data for {silent:.2f} s")
                        break
            except Exception as exc:  # a bug in a callback must not end the watching of a device
                log.exception("%s: link supervision failed", self.name)
                self.state, self.reason = "fault", f"internal error: {exc}"
                self._stop.wait(self.retry)
            finally:
                self.device = None
                self._close(dev)

    def _close(self, dev: Any) -> None:
        try:
            dev.close()
        except Exception as exc:  # a vanished device may fail to say goodbye; it is closed anyway
            log.debug("%s: close failed: %s", self.name, exc)

    def stop(self, timeout: float | None = 1.5) -> None:
        """Stop watching and close the device (the driver stops the device's output); with
        ``timeout=None`` only ask, and :meth:`join` later (several links close in parallel)."""
        self._stop.set()
        if timeout is not None:
            self.join(timeout)

    def join(self, timeout: float) -> None:
        if self._thread.ident is not None:
            self._thread.join(timeout)

    def snapshot(self) -> dict[str, Any]:
        dev = self.device
        counters = getattr(dev, "counters", None) if dev is not None else None
        return {"link": self.state, "reason": self.reason or None, "faults": self.faults,
                "recoveries": self.recoveries, "rate": round(self.rate.hz(), 2),
                "driver": getattr(dev, "link_state", None), "counters": dict(counters or {})}
