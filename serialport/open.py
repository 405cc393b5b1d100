"""Open a serial port (device path or pyserial URL), explaining every failure (:mod:`serialport.diagnose`)."""

from __future__ import annotations

import logging
import re

import serial

from serialport.diagnose import explain
from serialport.usb import adapter_of, check_latency

log = logging.getLogger(__name__)

_URL = re.compile(r"^[a-z][a-z0-9+.-]*://")
_seen: dict[str, str] = {}  # port -> adapter last logged: log it again only when it changed


def open_port(port: str, baudrate: int, *, timeout: float, write_timeout: float = 1.0,
              what: str = "the device", exclusive: bool = True) -> serial.SerialBase:
    """``port`` at ``baudrate``, 8N1, raw, read timeout ``timeout`` s.

    A device path is opened with an exclusive lock (``exclusive``), its USB adapter (VID:PID,
    driver) is logged, and an FTDI latency timer is set to 1 ms (or a warning says how).
    Raises :class:`~serialport.diagnose.PortError` naming the cause and the remedy."""
    url = bool(_URL.match(port))
    kwargs = {} if url else {"exclusive": exclusive}
    try:
        ser = serial.serial_for_url(port, baudrate=baudrate, timeout=timeout, write_timeout=write_timeout,
                                    **kwargs)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise explain(port, exc, baudrate, what) from exc
    if not url:
        adapter = adapter_of(port)
        text = str(adapter) if adapter else "no USB adapter in sysfs (a built-in port, a pty)"
        if _seen.get(port) != text:
            _seen[port] = text
            log.info("%s on %s: %s", what, port, text)
        check_latency(port, ser)
    return ser
