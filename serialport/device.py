"""The device side of a serial line: what both emulators share (a thread on a pty master fd).

A real device's transmitter never waits for the host: while the thread runs the fd is non-blocking
and output nobody reads is lost, not queued (:meth:`DeviceThread._transmit` says how much was lost).
"""

from __future__ import annotations

import abc
import os
import threading


class DeviceThread(abc.ABC):
    """A device running :meth:`_run` in a background thread on ``fd`` until :meth:`stop`.

    Subclasses loop in :meth:`_run` while ``self._stop`` is clear; :meth:`_starting` runs just
    before the thread starts (reset clocks there). A context manager: ``with Emulator(fd): ...``.
    """

    thread_name = "device"

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._was_blocking = True

    def _starting(self) -> None:
        """Called on :meth:`start` before the thread runs (nothing to do by default)."""
        return None

    @abc.abstractmethod
    def _run(self) -> None:
        """The device loop; returns once ``self._stop`` is set."""

    def start(self):
        """Power on: run the device in a background thread; returns self."""
        if self._thread is None:
            self._was_blocking = os.get_blocking(self.fd)
            os.set_blocking(self.fd, False)
            self._stop.clear()
            self._starting()
            self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Power off: stop the thread (the fd stays open; a new device may take it over)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
            try:
                os.set_blocking(self.fd, self._was_blocking)
            except OSError:
                pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _transmit(self, data: bytes) -> int:
        """Write ``data`` without waiting; returns the bytes lost (nobody reading, a full buffer, no
        host on the pty: EAGAIN/EIO), as on a real line."""
        try:
            n = os.write(self.fd, data)
        except OSError:
            n = 0
        return len(data) - n
