"""LMS2xx commands, mode codes and the data blocks both sides exchange (spec lms2xx.md §2.3, §2.6).

Pure values and functions only: the reader builds requests and checks replies with them, the
emulator parses the same requests and builds the replies.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

# Commands (host -> LMS); the reply code is the command | 0x80 unless noted.
RESET = 0x10  # reply 0x91, later 0x90 (power-on) at 9600 baud
SWITCH_MODE = 0x20
REQUEST_VALUES = 0x30
REQUEST_STATUS = 0x31
REQUEST_TYPE = 0x3A
SWITCH_VARIANT = 0x3B
REQUEST_CONFIG = 0x74
CONFIGURE = 0x77

# Replies that are not command | 0x80.
POWER_ON = 0x90
RESET_CONFIRM = 0x91
NOT_ACKNOWLEDGED = 0x92  # "incorrect command"
VALUES = REQUEST_VALUES | 0x80  # 0xB0, also streamed in continuous mode


def reply_code(command: int) -> int:
    """The code of the device's answer to ``command`` (0x10 -> 0x91, otherwise command | 0x80)."""
    return RESET_CONFIRM if command == RESET else command | 0x80


# 0x20 operating modes.
INSTALLATION = 0x00
CONTINUOUS = 0x24
ON_REQUEST = 0x25  # power-on default; "stop continuous output"
MODE_OK, MODE_REFUSED, MODE_LMI_FAULT = 0, 1, 2

# 0x20 mode code -> baud rate. 500000 needs RS-422.
BAUD_CODES = {0x42: 9600, 0x41: 19200, 0x40: 38400, 0x48: 500000}
BAUD_MODES = {b: m for m, b in BAUD_CODES.items()}
POWER_ON_BAUD = 9600

PASSWORD = b"SICK_LMS"


def password_for(type_string: str) -> bytes:
    """Installation-mode password: "SICK_" + the type's first three letters (Player's rule)."""
    family = type_string[:3].upper()
    return b"SICK_" + (family.encode("ascii") if family in ("LMS", "PLS", "LMI") else b"LMS")


# Variants (0x3B): field of view in degrees -> allowed resolutions in 1/100 degree.
VARIANTS = {180: (100, 50), 100: (100, 50, 25)}


def variant_data(fov: int, resolution_cdeg: int) -> bytes:
    """0x3B data: angle and resolution, uint16 LE each (resolution in 1/100 degree)."""
    return struct.pack("<HH", fov, resolution_cdeg)


@dataclass(frozen=True)
class VariantReply:
    """0xBB data: accepted flag, then the variant the device now has (degrees, 1/100 degree)."""

    accepted: bool
    fov: int
    resolution_cdeg: int

    @classmethod
    def parse(cls, data: bytes) -> VariantReply:
        if len(data) < 5:
            raise ValueError(f"0xBB reply needs 5 data bytes, got {data.hex(' ')}")
        fov, res = struct.unpack_from("<HH", data, 1)
        return cls(data[0] != 0, fov, res)

    def encode(self) -> bytes:
        return bytes((int(self.accepted),)) + variant_data(self.fov, self.resolution_cdeg)


# Measuring units: config byte 7 code and count-word bits 14-15 code, and metres per unit.
UNITS = {"cm": 0x00, "mm": 0x01, "10cm": 0x02}
UNIT_NAMES = {v: k for k, v in UNITS.items()}
METRES_PER_UNIT = {"mm": 0.001, "cm": 0.01, "10cm": 0.1}

# Measuring modes (config byte 6): number of range bits; the bits above are flags.
RANGE_BITS = {0x00: 13, 0x01: 13, 0x02: 13, 0x03: 14, 0x04: 14, 0x05: 15, 0x06: 15, 0x0F: 16}

CONFIG_LEN = 34  # data bytes after the CMD byte (sicktoolbox sends 34 + CMD; ARIA 33; Player 7)
_IDX_AVAILABILITY, _IDX_MODE, _IDX_UNITS = 5, 6, 7  # counted from CMD = 0 (spec §2.3)


@dataclass(frozen=True)
class ConfigBlock:
    """The 0x74/0x77 configuration block: ``raw`` is its data after the CMD byte (index 1 first).

    Only measuring mode, units and availability are interpreted; everything else is carried
    unchanged, which is why the reader edits the block the device reported (0xF4) rather than
    writing a fresh one.
    """

    raw: bytes

    @classmethod
    def default(cls) -> ConfigBlock:
        """A plausible factory block: stop threshold 70 (ARIA's), mode 0, mm, restart settings 2/2."""
        raw = bytearray(CONFIG_LEN)
        raw[2] = 70
        raw[_IDX_UNITS - 1] = UNITS["mm"]
        raw[9], raw[10] = 2, 2
        return cls(bytes(raw))

    def _get(self, idx: int) -> int:
        return self.raw[idx - 1] if len(self.raw) >= idx else 0

    @property
    def mode(self) -> int:
        """Measuring mode (0x00-0x06, 0x0F, 0x3F)."""
        return self._get(_IDX_MODE)

    @property
    def units(self) -> str:
        """ "mm", "cm" or "10cm" (unknown codes read as "mm")."""
        return UNIT_NAMES.get(self._get(_IDX_UNITS), "mm")

    @property
    def availability(self) -> int:
        return self._get(_IDX_AVAILABILITY)

    def with_settings(self, *, mode: int, units: str) -> ConfigBlock:
        """This block with measuring mode and units replaced (padded to at least 7 bytes)."""
        raw = bytearray(self.raw.ljust(_IDX_UNITS, b"\0"))
        raw[_IDX_MODE - 1] = mode
        raw[_IDX_UNITS - 1] = UNITS[units]
        return ConfigBlock(bytes(raw))

    def overlay(self, data: bytes) -> ConfigBlock:
        """This block with its leading bytes replaced by ``data`` (a 0x77 block of any length)."""
        return ConfigBlock(bytes(data[:CONFIG_LEN]) + self.raw[len(data) :])

    def is_valid(self) -> bool:
        return self.mode in RANGE_BITS and self._get(_IDX_UNITS) in UNIT_NAMES


# 0x31 status block: Player reads fov and resolution at payload[107..110] (index 0 = 0xB1).
STATUS_DATA_LEN = 152
_STATUS_VARIANT_AT = 107 - 1  # in the data (after the reply code)


def status_data(version: str, fov: int, resolution_cdeg: int) -> bytes:
    """A 0xB1 status block (data after the code, before STATUS) with the fields clients read."""
    raw = bytearray(STATUS_DATA_LEN)
    text = version.encode("ascii")[:7]
    raw[: len(text)] = text
    raw[_STATUS_VARIANT_AT : _STATUS_VARIANT_AT + 4] = variant_data(fov, resolution_cdeg)
    return bytes(raw)


def status_variant(data: bytes) -> tuple[int, int]:
    """(fov degrees, resolution 1/100 degree) from a 0xB1 reply's data."""
    return struct.unpack_from("<HH", data, _STATUS_VARIANT_AT)
