"""Typed errors of the LMS2xx reader, each deriving from the builtin a caller would catch.

Messages say what was expected, what arrived and what to check (port, baud, power, cable,
permissions). ``service.cli`` prints them as one line.
"""

from __future__ import annotations


class LaserError(Exception):
    """Base of every error raised by :mod:`laser`."""


class ProtocolError(LaserError, ValueError):
    """The device answered, but not what the protocol says it should (or refused a request)."""


class ConfigError(LaserError, ValueError):
    """A requested setting the LMS2xx cannot have (resolution, field of view, units, mode, baud)."""


class LinkLost(LaserError, ConnectionError):
    """No (intelligible) answer from the device: power, cable, port, baud or a reboot."""


# Appended to link errors: the usual causes, in the order worth checking.
CHECKS = (
    "check that the LMS is powered (it needs ~35 s after power-on before it answers), "
    "the port name and its permissions (group dialout), the cable (RS-232 for 9600-38400 baud; "
    "500000 baud needs RS-422) and that no other program holds the port"
)
