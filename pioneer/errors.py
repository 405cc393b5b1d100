"""Typed errors of the Pioneer driver, each deriving from the builtin a caller would catch.

Messages say what was expected, what arrived and what to check (port, baud, power, cable,
permissions). ``service.cli`` prints them as one line, so they never contain a newline.
"""

from __future__ import annotations


class PioneerError(Exception):
    """Base of every error raised by :mod:`pioneer`."""


class ProtocolError(PioneerError, ValueError):
    """Bytes that are not P2OS: a bad frame, a packet too short for its type, an unexpected reply."""


class LinkLost(PioneerError, ConnectionError):
    """No (intelligible) answer from the robot: power, cable, port, baud, or another program."""


class PortUnavailable(LinkLost):
    """The serial port could not be opened at all (name, permissions, in use)."""


# Appended to link errors: the usual causes, in the order worth checking.
CHECKS = (
    "check that the robot is powered on (the P2OS status LED blinks while it waits for a client), "
    "the port name, the baud (P2OS starts at 9600), the serial cable to the robot's host port "
    "(straight-through, not null-modem), that no other program (ARIA, Player, ROS) holds the port, "
    "and its permissions (add yourself to the dialout group, then log in again)"
)
