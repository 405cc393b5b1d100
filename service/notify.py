"""systemd's notify protocol without a dependency: one datagram to ``$NOTIFY_SOCKET``.

``Type=notify`` units wait for ``READY=1``; ``WatchdogSec=`` expects ``WATCHDOG=1`` at least once
per interval (``$WATCHDOG_USEC``, microseconds), sent from the main work loop so that a wedged loop
stops the pings; ``STOPPING=1`` says shutdown began. Outside systemd (no ``$NOTIFY_SOCKET``) every
call is a no-op, so the service runs the same from a terminal.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class Notifier:
    """Sends notify messages to ``socket_path`` (default ``$NOTIFY_SOCKET``; '@' = abstract)."""

    def __init__(self, socket_path: str | None = None, environ: dict[str, str] | None = None):
        env = os.environ if environ is None else environ
        self.path = env.get("NOTIFY_SOCKET", "") if socket_path is None else socket_path
        self._sock: socket.socket | None = None
        self.dropped = 0
        self.watchdog_interval = watchdog_interval(env)

    @property
    def enabled(self) -> bool:
        return bool(self.path)

    def send(self, *fields: str) -> bool:
        """Send ``fields`` (``"READY=1"``, ``"STATUS=..."``) as one datagram; False when not sent.

        Failures are logged, never raised: losing a status line must not stop the robot's service.
        The socket is non-blocking: a receiver that does not read (its queue holds only
        ``net.unix.max_dgram_qlen`` datagrams) must not wedge the main loop; the message is dropped.
        """
        if not self.path:
            return False
        addr = "\0" + self.path[1:] if self.path.startswith("@") else self.path
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)
            self._sock.sendto("\n".join(fields).encode("utf-8"), addr)
            return True
        except BlockingIOError:
            self.dropped += 1
            log.debug("sd_notify to %s: the receiver's queue is full; message dropped", self.path)
            return False
        except OSError as exc:
            log.warning("sd_notify to %s failed: %s", self.path, exc)
            return False

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1", *([f"STATUS={status}"] if status else []))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def stopping(self, status: str = "") -> bool:
        return self.send("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text.replace(chr(10), ' ')}")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval(environ: dict[str, str] | None = None) -> float | None:
    """The watchdog timeout (s) systemd expects pings within, or None when there is none for us.

    ``WATCHDOG_PID``, when set, names the process meant; another PID (a child) must not ping.
    """
    env = os.environ if environ is None else environ
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    pid = env.get("WATCHDOG_PID")
    if usec <= 0 or (pid and pid != str(os.getpid())):
        return None
    return usec / 1e6
