"""SICK LMS2xx: telegram codec and CRC, host-side reader, device-side emulator.

``from laser import LMS2xx, LaserScan`` for the reader and its scans; the emulator is
:class:`laser.emulator.LMS2xxEmulator` (device side, on a pty master).
"""

from laser.errors import ConfigError, LaserError, LinkLost, ProtocolError
from laser.reader import LinkEvent, LMS2xx, Timeouts
from laser.values import LaserScan, decode_b0, encode_b0, make_scan

__all__ = [
    "ConfigError",
    "LMS2xx",
    "LaserError",
    "LaserScan",
    "LinkEvent",
    "LinkLost",
    "ProtocolError",
    "Timeouts",
    "decode_b0",
    "encode_b0",
    "make_scan",
]
