"""LMS2xx telegram framing (spec lms2xx.md §2.1-2.2) and an incremental, resynchronising reader.

A telegram on the wire::

    STX(0x02) | ADR | LEN_lo LEN_hi | CMD | DATA... | [STATUS] | CRC_lo CRC_hi

LEN counts CMD + DATA (+ STATUS); the CRC covers STX..STATUS. Replies from the device carry
``ADR | 0x80`` and end their payload with a STATUS byte; host requests have neither. Single ACK
(0x06) and NAK (0x15) bytes travel outside any frame.

:class:`FrameReader` is shared by the host-side reader and the device emulator: it turns arbitrary
chunks of bytes into :class:`Telegram` values and counts everything it had to drop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from laser.crc import crc16

STX = 0x02
ACK = 0x06
NAK = 0x15
REPLY_BIT = 0x80  # set in ADR of every device -> host telegram
MAX_PAYLOAD = 812  # LEN limit: sicktoolbox SICK_LMS_2XX_MSG_PAYLOAD_MAX_LEN
HEADER = 4  # STX, ADR, LEN_lo, LEN_hi
OVERHEAD = HEADER + 2  # + CRC


@dataclass(frozen=True)
class Telegram:
    """One framed telegram. ``data`` excludes CMD and STATUS; ``status`` is None for host requests."""

    command: int
    data: bytes = b""
    address: int = 0x00
    status: int | None = None

    @property
    def is_reply(self) -> bool:
        """True for device -> host telegrams (ADR has the 0x80 bit)."""
        return bool(self.address & REPLY_BIT)

    @property
    def size(self) -> int:
        """Bytes on the wire: STX, ADR, LEN (2), CMD, data, [STATUS], CRC (2)."""
        return OVERHEAD + 1 + len(self.data) + (self.status is not None)

    def encode(self) -> bytes:
        """The telegram's bytes on the wire, CRC included."""
        return encode_telegram(self.command, self.data, address=self.address, status=self.status)


def encode_telegram(
    command: int, data: bytes = b"", *, address: int = 0x00, status: int | None = None
) -> bytes:
    """Frame ``command`` + ``data`` (+ ``status`` for replies); raises ValueError if too long."""
    payload = bytes((command,)) + bytes(data) + (b"" if status is None else bytes((status,)))
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(
            f"telegram payload of {len(payload)} bytes exceeds the LMS2xx limit of {MAX_PAYLOAD}"
        )
    head = bytes((STX, address, len(payload) & 0xFF, len(payload) >> 8)) + payload
    crc = crc16(head)
    return head + bytes((crc & 0xFF, crc >> 8))


def request(command: int, *data: int | bytes) -> bytes:
    """A host -> LMS telegram to address 0: ``request(0x20, 0x24)`` is ``02 00 02 00 20 24 34 08``."""
    body = b"".join(d if isinstance(d, bytes | bytearray) else bytes((d,)) for d in data)
    return encode_telegram(command, body)


def reply(command: int, data: bytes = b"", *, status: int = 0x10, address: int = REPLY_BIT) -> bytes:
    """An LMS -> host telegram; 0x10 is the "OK" status real scanners send (spec §2.5)."""
    return encode_telegram(command, data, address=address, status=status)


@dataclass
class FrameCounters:
    """What a :class:`FrameReader` has seen: good telegrams and every kind of loss, in bytes or events."""

    telegrams: int = 0
    bad_crc: int = 0  # candidate frames whose CRC failed (the search restarts after their STX)
    oversize: int = 0  # STX followed by LEN 0 or LEN > 812
    truncated: int = 0  # candidates abandoned by flush() before their last byte arrived
    bytes_skipped: int = 0  # bytes outside any good frame, ACK/NAK included
    acks: int = 0
    naks: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class FrameReader:
    """Incremental telegram parser: ``feed(bytes) -> list[Telegram]``.

    Finds STX, bounds LEN to 1..812, checks the CRC. After a bad CRC or an impossible length it
    restarts the search at the byte after that STX (not after the whole claimed frame), so a real
    telegram hidden inside a garbage "frame" is still found, and found at once: a candidate that is
    still incomplete is dropped as soon as a complete good frame appears inside it. Never raises.
    """

    counters: FrameCounters = field(default_factory=FrameCounters)
    _buf: bytearray = field(default_factory=bytearray, repr=False)

    def feed(self, data: bytes) -> list[Telegram]:
        """Append ``data`` and return every telegram completed by it, in order."""
        return [t for t, _ in self.feed_positions(data)]

    def feed_positions(self, data: bytes) -> list[tuple[Telegram, int]]:
        """Like :meth:`feed`, with the number of bytes of ``data`` that followed each telegram's last
        byte (0 for a telegram ending ``data``), from which a caller timestamps each telegram."""
        self._buf += data
        found: list[tuple[Telegram, int]] = []
        end = self._parse(found)
        del self._buf[:end]
        return found

    def flush(self) -> list[Telegram]:
        """Give up on an incomplete candidate frame (e.g. after a silence on the line) and return any
        telegram found in the bytes it had claimed."""
        found: list[tuple[Telegram, int]] = []
        while self._buf:
            self.counters.truncated += 1
            self._skip(1)
            del self._buf[:1]
            end = self._parse(found)
            del self._buf[:end]
        return [t for t, _ in found]

    def reset(self) -> None:
        """Discard buffered bytes (after flushing the port or changing baud); counters are kept."""
        self.counters.bytes_skipped += len(self._buf)
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a candidate frame."""
        return len(self._buf)

    def _skip(self, n: int, start: int = 0) -> None:
        chunk = self._buf[start : start + n]
        self.counters.bytes_skipped += n
        self.counters.acks += chunk.count(ACK)
        self.counters.naks += chunk.count(NAK)

    def _parse(self, found: list[tuple[Telegram, int]]) -> int:
        """Consume complete frames from ``_buf``; return how many leading bytes are done with.

        ``found`` gets (telegram, number of buffered bytes after its last byte)."""
        buf = self._buf
        n = len(buf)
        i = 0
        while True:
            s = buf.find(STX, i)
            if s < 0:
                self._skip(n - i, i)
                return n
            if s > i:
                self._skip(s - i, i)
            i = s
            if n - i < HEADER:
                return i
            length = buf[i + 2] | (buf[i + 3] << 8)
            if length == 0 or length > MAX_PAYLOAD:
                self.counters.oversize += 1
                self._skip(1, i)
                i += 1
                continue
            end = i + HEADER + length + 2
            if end > n:
                if not self._complete_frame_after(i + 1):
                    return i
                # A good telegram already sits inside the bytes this STX claims: the STX was noise
                # (a real frame is sent in one piece), so give it up now rather than stall.
                self.counters.bad_crc += 1
            elif _crc_ok(buf, i, end):
                found.append((_telegram(bytes(buf[i : end - 2])), n - end))
                self.counters.telegrams += 1
                i = end
                continue
            else:
                self.counters.bad_crc += 1
            self._skip(1, i)
            i += 1

    def _complete_frame_after(self, start: int) -> bool:
        """Whether a complete frame with a good CRC starts at some STX at or after ``start``."""
        buf = self._buf
        n = len(buf)
        j = buf.find(STX, start)
        while 0 <= j <= n - OVERHEAD - 1:
            length = buf[j + 2] | (buf[j + 3] << 8)
            end = j + HEADER + length + 2
            if 0 < length <= MAX_PAYLOAD and end <= n and _crc_ok(buf, j, end):
                return True
            j = buf.find(STX, j + 1)
        return False


def _crc_ok(buf: bytearray, start: int, end: int) -> bool:
    return crc16(memoryview(buf)[start : end - 2]) == (buf[end - 2] | (buf[end - 1] << 8))


def _telegram(body: bytes) -> Telegram:
    """Split a CRC-checked STX..STATUS run into a :class:`Telegram`."""
    address, command = body[1], body[4]
    if address & REPLY_BIT and len(body) > HEADER + 1:
        return Telegram(command, body[5:-1], address, body[-1])
    return Telegram(command, body[5:], address, None)
