"""How long LMS2xx telegrams and scans take (spec lms2xx.md §2.6): serial line and mirror.

Both the emulator (to stream at the real device's rate) and the reader (to timestamp telegrams and
to notice a silent device) use these.
"""

from __future__ import annotations

MIRROR_HZ = 75.0  # mirror revolutions per second; one 180 deg scan at 1 deg per revolution
BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop


def transmit_time(nbytes: int, baud: int) -> float:
    """Seconds ``nbytes`` take on the line at ``baud`` (8N1)."""
    return nbytes * BITS_PER_BYTE / baud


def b0_size(count: int, realtime_index: bool = False) -> int:
    """Bytes of a 0xB0 telegram: STX ADR LEN(2) CMD COUNT(2) ``count`` values [index] STATUS CRC(2)."""
    return 10 + 2 * count + int(realtime_index)


def interlace(resolution_deg: float) -> int:
    """Mirror revolutions per complete scan: 1 at 1 deg, 2 at 0.5 deg, 4 at 0.25 deg."""
    return max(1, round(1.0 / resolution_deg)) if resolution_deg > 0 else 1


def mirror_period(resolution_deg: float) -> float:
    """Seconds between complete scans as the mirror alone allows."""
    return interlace(resolution_deg) / MIRROR_HZ


def scan_period(count: int, resolution_deg: float, baud: int) -> float:
    """Seconds between 0xB0 telegrams in continuous mode: the mirror or the line, whichever is slower.

    181 values at 38400 baud: 372 bytes = 96.9 ms (10.3 Hz); at 500000: 13.3 ms (the 75 Hz mirror).
    """
    return max(mirror_period(resolution_deg), transmit_time(b0_size(count), baud))


def sweep_time(fov_deg: float, resolution_deg: float) -> float:
    """Seconds from the first ray to the last of one complete (possibly interlaced) scan."""
    return (interlace(resolution_deg) - 1 + fov_deg / 360.0) / MIRROR_HZ
