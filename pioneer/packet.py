"""P2OS packet framing (spec p2os.md §1.1): ``FA FB N data[0..N-3] CHK_hi CHK_lo``.

``N`` counts the data bytes plus the two checksum bytes. The checksum is the 16-bit sum of the data
as big-endian byte pairs, an odd last byte XORed into the low byte, sent high byte first (the only
big-endian integer of P2OS). Both directions use the same framing, so the driver (host side) and
the emulator (robot side) share :func:`frame` and :class:`PacketReader`.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

SYNC = b"\xfa\xfb"
MIN_COUNT = 3  # one data byte (the command or packet type) plus the checksum
# The P2 manual: P2OS ignores packets whose byte count exceeds 200 (ROS-p2os refuses more than 198
# bytes in total). ARIA accepts any count; a robot-side reader must not, a host-side one need not.
MAX_COUNT = 200
#: s. A packet goes out in one piece: a partial packet with no byte for this long never completes
#: (its header was line noise whose byte count swallowed what followed). Three FTDI latency
#: periods (16 ms each by default) of silence.
STALL_S = 0.05


# One big-endian pair reader per data length (at most 198 bytes).
_PAIRS = [struct.Struct(f">{n // 2}H").unpack_from for n in range(256)]


def checksum(data: bytes) -> int:
    """The P2OS checksum of a packet's data bytes (the command/type byte through the last argument)."""
    n = len(data)
    pairs = _PAIRS[n] if n < 256 else struct.Struct(f">{n // 2}H").unpack_from
    c = sum(pairs(data)) & 0xFFFF
    if len(data) & 1:
        c ^= data[-1]
    return c


def frame(data: bytes) -> bytes:
    """The complete packet carrying ``data`` (at least the command/type byte, at most 198 bytes)."""
    if not 1 <= len(data) <= MAX_COUNT - 2:
        raise ValueError(f"a P2OS packet carries 1 to {MAX_COUNT - 2} data bytes, not {len(data)}")
    c = checksum(data)
    return b"%s%c%s%c%c" % (SYNC, len(data) + 2, data, c >> 8, c & 0xFF)


class Packet(NamedTuple):
    """One intact packet: ``data`` is everything between the byte count and the checksum.
    (An immutable record; a NamedTuple because the reader makes one per packet on the hot path.)"""

    data: bytes

    @property
    def type(self) -> int:
        """The first data byte: the command number (to the robot) or the packet type (from it)."""
        return self.data[0]

    @property
    def payload(self) -> bytes:
        return self.data[1:]

    def to_bytes(self) -> bytes:
        return frame(self.data)


class PacketReader:
    """Incremental framer: :meth:`feed` bytes as they arrive, get the intact packets back.

    Resynchronises on the next ``FA FB`` after garbage (ARIA's ``"WMS2\\r"``, line noise, a packet
    cut short). A header whose byte count is impossible (< 3 or > ``max_count``) or whose checksum
    fails is dropped by skipping only its first byte, so an intact packet that the bad one seemed
    to swallow is still found. Counters: ``packets_ok``, ``bad_checksums``, ``bad_counts``,
    ``bytes_skipped`` (every byte not delivered inside an intact packet), ``stalled`` (partial
    packets given up by :meth:`expire`).
    """

    __slots__ = ("_buf", "bad_checksums", "bad_counts", "bytes_skipped", "last_rx", "max_count", "packets_ok",
                 "stalled")

    def __init__(self, max_count: int = MAX_COUNT) -> None:
        self._buf = b""
        self.max_count = max_count
        self.packets_ok = 0
        self.bad_checksums = 0
        self.bad_counts = 0
        self.bytes_skipped = 0
        self.stalled = 0
        self.last_rx = 0.0  # host time (s) of the last read that brought bytes, for receive()

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return every packet completed by it, in order."""
        # Work on one immutable copy per call: packet bodies are then plain slices (one copy each).
        buf = self._buf + bytes(data) if self._buf else bytes(data)
        n = len(buf)
        out: list[Packet] = []
        i = 0
        while True:
            j = buf.find(SYNC, i)
            if j < 0:
                # A trailing 0xFA may be the first half of the next header.
                keep = n - 1 if n > i and buf[n - 1] == 0xFA else n
                self.bytes_skipped += keep - i
                i = keep
                break
            self.bytes_skipped += j - i
            i = j
            if j + 3 > n:
                break
            count = buf[j + 2]
            if count < MIN_COUNT or count > self.max_count:
                self.bad_counts += 1
                self.bytes_skipped += 1
                i = j + 1
                continue
            end = j + 3 + count
            if end > n:
                break
            body = buf[j + 3 : end - 2]
            if checksum(body) != (buf[end - 2] << 8 | buf[end - 1]):
                self.bad_checksums += 1
                self.bytes_skipped += 1
                i = j + 1
                continue
            out.append(Packet(body))
            self.packets_ok += 1
            i = end
        self._buf = buf[i:]
        return out

    def receive(self, data: bytes, now: float) -> list[Packet]:
        """:meth:`feed` for a read made at host time ``now`` (s). A read that brought nothing, while a
        partial packet has waited more than :data:`STALL_S` since the last bytes, expires it
        (:meth:`expire`)."""
        if data:
            self.last_rx = now
            return self.feed(data)
        if self._buf and now - self.last_rx > STALL_S:
            return self.expire()
        return []

    def expire(self) -> list[Packet]:
        """The line fell silent with a packet pending (see :data:`STALL_S`): that header was noise.

        Its first byte is skipped and the rest re-read, so intact packets its bogus byte count
        swallowed (a client's SYNC0 after a burst of garbage) are delivered; any other partial
        packet in the rest is dead too and goes the same way. Returns the packets found.
        """
        out: list[Packet] = []
        while self._buf:
            rest, self._buf = self._buf[1:], b""
            self.bytes_skipped += 1
            self.stalled += 1
            out += self.feed(rest)
        return out

    def clear(self) -> None:
        """Forget a partly received packet (the port was flushed or reopened); counters stay."""
        self._buf = b""

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a packet."""
        return len(self._buf)

    def counters(self) -> dict[str, int]:
        return {
            "packets_ok": self.packets_ok,
            "bad_checksums": self.bad_checksums,
            "bad_counts": self.bad_counts,
            "bytes_skipped": self.bytes_skipped,
            "stalled": self.stalled,
        }
