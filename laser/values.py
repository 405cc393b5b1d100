"""Measured values (0xB0, spec lms2xx.md §2.4): decode into :class:`LaserScan` and encode back.

Payload: ``B0 | COUNT(u16) | COUNT x VALUE(u16) | [real-time index] | STATUS``, all little-endian.

COUNT word: bits 0-9 number of values, 11-12 partial-scan index (+0.25 deg each), 13 partial
flag, 14-15 units (00 cm, 01 mm, 10 10 cm).

VALUE word: the low ``RANGE_BITS[mode]`` bits are the range, the bits above are flags:
modes 0/1/2: 13-bit range; bits 13,14,15 = field A, field B, dazzle (mode 0), reflector value
0-7 (mode 1) or fields A, B, C (mode 2). Modes 3/4: 14-bit range; bits 14-15 = reflector or
fields A/B. Modes 5/6: 15-bit range; bit 15 = reflector or field A. Mode 0x0F: 16-bit range.
``flags`` holds those bits shifted down (bit 0 = the lowest flag bit).

The all-ones range code (8191 in modes 0-2: 8.191 m in mm, 81.91 m in cm) means no return.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from laser.protocol import METRES_PER_UNIT, RANGE_BITS, UNIT_NAMES, UNITS, VALUES
from laser.telegram import REPLY_BIT, Telegram, encode_telegram
from laser.timing import sweep_time

COUNT_MASK = 0x03FF
PARTIAL_FLAG = 1 << 13

# Values per complete scan -> (field of view deg, resolution deg): the variants of spec §2.4.
COUNT_VARIANTS = {
    181: (180, 1.0),
    361: (180, 0.5),
    721: (180, 0.25),
    101: (100, 1.0),
    201: (100, 0.5),
    401: (100, 0.25),
}


def max_code(mode: int) -> int:
    """The all-ones range code of measuring ``mode`` (the device's "no return")."""
    return (1 << RANGE_BITS.get(mode, 13)) - 1


@lru_cache(maxsize=64)
def _angles(count: int, fov: float, resolution: float, offset_deg: float) -> np.ndarray:
    a = np.radians(-fov / 2.0 + offset_deg + resolution * np.arange(count))
    a.flags.writeable = False
    return a


def scan_angles(count: int, fov_deg: float, resolution_deg: float, offset_deg: float = 0.0) -> np.ndarray:
    """Beam angles in radians, sensor frame (x forward, counter-clockwise positive): value 0 is the
    rightmost beam at -fov/2. Read-only and shared between scans of the same geometry."""
    return _angles(count, float(fov_deg), float(resolution_deg), float(offset_deg))


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One LMS2xx scan, sensor frame, SI units.

    - ``t``: host ``time.monotonic()`` seconds of the scan's first ray (beam 0): the telegram's
      last byte's arrival minus its transmission time at the baud, minus the mirror's sweep
      (:func:`laser.timing.sweep_time`); the same clock as the Pioneer's odometry stamps.
    - ``ranges``: float32 metres per beam; no-return beams read :attr:`max_range` (see :attr:`no_return`).
    - ``angles``: float64 radians, -fov/2 .. +fov/2 counter-clockwise (value 0 on the right).
    - ``flags``: uint8 per beam, the value word's bits above the range (module docstring).
    - ``resolution_deg``, ``fov_deg``: the variant, in degrees as the device states it.
    - ``units``: "mm", "cm" or "10cm" as sent; ``mode``: measuring mode; ``status``: status byte.
    - ``partial``/``partial_index``: partial (interlaced) scan and its 0.25 deg offset index.
    - ``scan_index``: the real-time index byte when the device sends one, else None.
    """

    t: float
    ranges: np.ndarray
    angles: np.ndarray
    flags: np.ndarray
    resolution_deg: float
    fov_deg: float
    units: str = "mm"
    mode: int = 0
    status: int = 0x10
    partial: bool = False
    partial_index: int = 0
    scan_index: int | None = None
    _raw: np.ndarray | None = field(default=None, repr=False)

    @property
    def count(self) -> int:
        return len(self.ranges)

    @property
    def max_range(self) -> float:
        """Metres of the no-return code: 8.191 (modes 0-2, mm), 81.91 (cm), 32.767 (mode 5, mm)..."""
        return max_code(self.mode) * METRES_PER_UNIT[self.units]

    @property
    def no_return(self) -> np.ndarray:
        """Boolean per beam: the device reported nothing within range."""
        return self.raw_ranges == max_code(self.mode)

    @property
    def raw_ranges(self) -> np.ndarray:
        """Range codes (uint16, in ``units``) as on the wire, without the flag bits."""
        if self._raw is not None:
            return self._raw
        return np.rint(self.ranges / np.float32(METRES_PER_UNIT[self.units])).astype(np.uint16)

    @property
    def angle_min(self) -> float:
        """Radians of the first beam."""
        return float(self.angles[0]) if self.count else -math.radians(self.fov_deg) / 2

    @property
    def angle_increment(self) -> float:
        """Radians between beams."""
        return math.radians(self.resolution_deg)

    @property
    def t_first_ray(self) -> float:
        """Host time of the first ray: :attr:`t` itself (kept for callers that name it)."""
        return self.t

    @property
    def t_last_ray(self) -> float:
        """Host time of the last ray: :attr:`t` plus the mirror's sweep (interlacing included)."""
        return self.t + sweep_time(self.fov_deg, self.resolution_deg)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LaserScan):
            return NotImplemented
        same_t = self.t == other.t or (math.isnan(self.t) and math.isnan(other.t))
        return (
            same_t
            and self._key() == other._key()
            and np.array_equal(self.raw_ranges, other.raw_ranges)
            and np.array_equal(self.flags, other.flags)
            and np.allclose(self.angles, other.angles)
        )

    def _key(self) -> tuple:
        return (
            self.resolution_deg,
            self.fov_deg,
            self.units,
            self.mode,
            self.status,
            self.partial,
            self.partial_index,
            self.scan_index,
        )

    __hash__ = None  # type: ignore[assignment]


def make_scan(
    ranges_m,
    *,
    fov_deg: float = 180,
    resolution_deg: float | None = None,
    units: str = "mm",
    mode: int = 0,
    flags=None,
    t: float = math.nan,
    status: int = 0x10,
    scan_index: int | None = None,
) -> LaserScan:
    """A scan as the device would report ``ranges_m`` (metres): quantised to ``units``, clipped to the
    mode's range codes, NaN/inf/negative/beyond-range -> no return. ``flags`` default to 0."""
    r = np.asarray(ranges_m, dtype=np.float64)
    unit = METRES_PER_UNIT[units]
    top = max_code(mode)
    with np.errstate(invalid="ignore"):
        codes = np.where(np.isfinite(r) & (r >= 0), np.rint(r / unit), top)
    raw = np.clip(codes, 0, top).astype(np.uint16)
    count = len(raw)
    res = resolution_deg if resolution_deg is not None else (fov_deg / (count - 1) if count > 1 else 1.0)
    f = np.zeros(count, np.uint8) if flags is None else np.asarray(flags, np.uint8)
    return LaserScan(
        t=t,
        ranges=(raw * np.float32(unit)).astype(np.float32),
        angles=scan_angles(count, fov_deg, res),
        flags=f,
        resolution_deg=res,
        fov_deg=fov_deg,
        units=units,
        mode=mode,
        status=status,
        scan_index=scan_index,
        _raw=raw,
    )


def decode_b0(
    telegram: Telegram, *, mode: int = 0, fov_deg: float | None = None, t: float = math.nan
) -> LaserScan:
    """Decode a 0xB0 telegram.

    ``mode`` is the measuring mode configured (it decides which bits are range and which flags; the
    telegram does not say). ``fov_deg`` is the variant's field of view; when None it is inferred
    from the count (181/361/721 -> 180 deg, 101/201/401 -> 100 deg). Raises ValueError on a
    telegram that is not a well-formed 0xB0.
    """
    data = telegram.data
    if telegram.command != VALUES or len(data) < 2:
        raise ValueError(
            f"expected a 0xB0 measured-values telegram, got command 0x{telegram.command:02X} "
            f"with {len(data)} data bytes"
        )
    (word,) = struct.unpack_from("<H", data)
    count = word & COUNT_MASK
    extra = len(data) - 2 - 2 * count
    if extra not in (0, 1):
        raise ValueError(
            f"0xB0 count word says {count} values ({2 + 2 * count} data bytes, +1 with a "
            f"real-time index) but the telegram carries {len(data)}"
        )
    unit_code = word >> 14
    if unit_code not in UNIT_NAMES:
        raise ValueError(f"0xB0 count word 0x{word:04X} has the invalid unit code 3 in bits 14-15")
    units = UNIT_NAMES[unit_code]
    bits = RANGE_BITS.get(mode)
    if bits is None:
        raise ValueError(f"measuring mode 0x{mode:02X} has no range values (modes {sorted(RANGE_BITS)})")
    values = np.frombuffer(data, dtype="<u2", count=count, offset=2)
    raw = (values & ((1 << bits) - 1)).astype(np.uint16)
    flags = (values >> bits).astype(np.uint8)
    fov, res = _geometry(count, fov_deg)
    partial = bool(word & PARTIAL_FLAG)
    index = (word >> 11) & 0x3
    return LaserScan(
        t=t,
        ranges=raw * np.float32(METRES_PER_UNIT[units]),
        angles=scan_angles(count, fov, res, 0.25 * index),
        flags=flags,
        resolution_deg=res,
        fov_deg=fov,
        units=units,
        mode=mode,
        status=telegram.status if telegram.status is not None else 0,
        partial=partial,
        partial_index=index,
        scan_index=data[-1] if extra else None,
        _raw=raw,
    )


def _geometry(count: int, fov_deg: float | None) -> tuple[float, float]:
    if fov_deg is None:
        fov_deg = COUNT_VARIANTS.get(count, (180, 0.0))[0]
    return float(fov_deg), (fov_deg / (count - 1) if count > 1 else 1.0)


def b0_data(scan: LaserScan) -> bytes:
    """The 0xB0 data (count word, values, optional real-time index) of ``scan``; STATUS not included."""
    bits = RANGE_BITS[scan.mode]
    word = (
        scan.count
        | (UNITS[scan.units] << 14)
        | (PARTIAL_FLAG if scan.partial else 0)
        | (scan.partial_index << 11)
    )
    values = (scan.raw_ranges.astype(np.uint32) | (scan.flags.astype(np.uint32) << bits)) & 0xFFFF
    tail = b"" if scan.scan_index is None else bytes((scan.scan_index,))
    return struct.pack("<H", word) + values.astype("<u2").tobytes() + tail


def encode_b0(scan: LaserScan, *, address: int = REPLY_BIT) -> bytes:
    """The whole 0xB0 telegram of ``scan`` as the device sends it (ADR 0x80, STATUS, CRC)."""
    return encode_telegram(VALUES, b0_data(scan), address=address, status=scan.status)
