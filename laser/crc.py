"""The SICK LMS2xx CRC16 (spec lms2xx.md §2.1).

For every byte ``b`` of STX..STATUS, with ``prev`` the byte before it (0 at the start)::

    crc = ((crc & 0x7FFF) << 1) ^ 0x8005  if crc & 0x8000  else  crc << 1     # shift first
    crc ^= b | (prev << 8)

The shift ``L`` is linear over GF(2) and the state starts at 0, so after ``n`` bytes

    crc = XOR_j  L^(n-1-j)(b_j)  ^  L^(n-2-j)(b_j << 8)

i.e. every byte contributes a term that depends only on its value and its distance ``k = n-1-j``
from the end. :data:`_TERMS` tabulates those terms (``k`` up to the longest telegram, 256 values
each), which turns the CRC of a whole telegram into one numpy gather and one XOR reduction.
"""

from __future__ import annotations

import numpy as np

POLY = 0x8005

# STX + ADR + 2 LEN + 812 payload bytes (CMD, DATA, STATUS): the longest run the CRC covers.
MAX_CRC_SPAN = 4 + 812


def crc16_reference(data: bytes) -> int:
    """The literal per-byte algorithm of ARIA, Player and sicktoolbox; slow, the oracle for tests."""
    crc = 0
    prev = 0
    for cur in data:
        crc = (((crc & 0x7FFF) << 1) ^ POLY) if crc & 0x8000 else (crc << 1) & 0xFFFF
        crc ^= cur | (prev << 8)
        prev = cur
    return crc


def _shift(x: np.ndarray) -> np.ndarray:
    """One application of ``L`` to an array of 16-bit states."""
    top = (x & 0x8000) != 0
    return (((x & 0x7FFF) << 1) ^ np.where(top, POLY, 0)).astype(np.uint16)


def _build_terms(span: int) -> np.ndarray:
    values = np.arange(256, dtype=np.uint16)
    lo = np.empty((span, 256), dtype=np.uint16)
    hi = np.empty((span, 256), dtype=np.uint16)
    lo[0], hi[0] = values, values << 8
    for k in range(1, span):
        lo[k], hi[k] = _shift(lo[k - 1]), _shift(hi[k - 1])
    terms = lo.copy()
    terms[1:] ^= hi[:-1]  # the last byte never serves as a "previous" byte
    return terms.reshape(-1)


_TERMS = _build_terms(MAX_CRC_SPAN)
# Flat index base of the term table for distance-from-end k, laid out so that a message of n bytes
# uses the last n entries: _BASES[MAX_CRC_SPAN - n + j] = (n - 1 - j) * 256.
_SHORT = 24
_BASES = np.arange(MAX_CRC_SPAN - 1, -1, -1, dtype=np.intp) * 256


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC16 of ``data`` (STX through STATUS), at most :data:`MAX_CRC_SPAN` bytes; table-driven."""
    n = len(data)
    if n <= _SHORT or n > MAX_CRC_SPAN:
        # Below a couple of dozen bytes numpy's call overhead costs more than the plain loop.
        return crc16_reference(bytes(data))
    idx = _BASES[MAX_CRC_SPAN - n :] + np.frombuffer(data, dtype=np.uint8)
    return int(np.bitwise_xor.reduce(_TERMS[idx]))
