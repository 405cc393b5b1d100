"""Pseudo-terminal pairs for the device emulators.

An emulator owns the *master* side of a pty; a driver opens the *slave* path with pyserial exactly
as it would open ``/dev/ttyUSB0``. Both ends are raw (8N1, no echo, no line discipline), as a real
serial port is after ``tcsetattr`` by ARIA, Player or pyserial.
"""

from __future__ import annotations

import os
import termios
import tty
from dataclasses import dataclass


@dataclass
class PtyPair:
    """A raw pty pair: ``master`` fd for the device side, ``path`` of the slave for the host side.

    ``slave_fd`` stays open for the pair's lifetime so that the master never sees a hang-up while
    the host side is closed and reopened (as a USB adapter stays present while a client restarts).
    """

    master: int
    slave_fd: int
    path: str

    def close(self) -> None:
        for fd in (self.master, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_pty() -> PtyPair:
    """Open a raw pty pair and return it (see :class:`PtyPair`)."""
    master, slave = os.openpty()
    for fd in (master, slave):
        tty.setraw(fd, termios.TCSANOW)
    return PtyPair(master=master, slave_fd=slave, path=os.ttyname(slave))


_SPEEDS = {getattr(termios, f"B{b}"): b for b in (
    0, 50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600,
    115200, 230400, 460800, 500000, 576000, 921600, 1000000) if hasattr(termios, f"B{b}")}


def line_speed(fd: int) -> int:
    """The baud rate (bits/s) the host side last set on this pty, read from either end's termios.

    A pty carries bytes at memory speed whatever the setting; emulators read it to behave as a
    device would at that speed (a device and host at different bauds see garbage).
    """
    attrs = termios.tcgetattr(fd)
    return _SPEEDS.get(attrs[5], 0)  # ospeed
