"""P2OS client commands (spec p2os.md §1.2, §1.4): numbers, argument encoding, robot-side parsing.

A command packet's data is the command number, then optionally one argument:

- ``0x3B`` + 2 bytes LSB first: a positive integer;
- ``0x1B`` + 2 bytes LSB first: a negative integer, sent as its **absolute value** (ARIA comInt);
- ``0x2B`` + length byte + bytes: a string (ARIA's comStr adds a NUL that the length excludes).

:func:`command` builds what a client sends; :func:`parse_command` is the lenient robot-side reading
of any client's packet (missing argument, ``SETO 3B`` without its integer bytes, trailing NUL).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from pioneer.packet import Packet, frame


class Command(IntEnum):
    """P2OS command numbers (ARIA ArCommands.h; ROS-p2os robot_params.hpp; P2 manual Table 6-5).

    0, 1 and 2 are SYNC0/1/2 during the handshake and PULSE/OPEN/CLOSE once it is complete.
    """

    SYNC0 = 0
    SYNC1 = 1
    SYNC2 = 2
    PULSE = 0
    OPEN = 1
    CLOSE = 2
    POLLING = 3
    ENABLE = 4
    SETA = 5
    SETV = 6
    SETO = 7
    MOVE = 8
    ROTATE = 9
    SETRV = 10
    VEL = 11
    HEAD = 12
    DHEAD = 13
    SAY = 15
    JOYINFO = 17
    CONFIG = 18
    ENCODER = 19
    SETRVDIR = 20
    RVEL = 21
    DCHEAD = 22
    SETRA = 23
    SONAR = 28
    STOP = 29
    DIGOUT = 30
    VEL2 = 32
    GRIPPER = 33
    ADSEL = 35
    GRIPPERVAL = 36
    GRIPREQUEST = 37
    IOREQUEST = 40
    PTUPOS = 41
    TTY2 = 42
    GETAUX = 43
    BUMPSTALL = 44
    TCM2 = 45
    JOYDRIVE = 47
    HOSTBAUD = 50
    AUX1BAUD = 51
    AUX2BAUD = 52
    E_STOP = 55
    E_STALL = 56
    GYRO = 58
    BATTERYINFO = 62
    ROTKP = 82
    ROTKV = 83
    ROTKI = 84
    TRANSKP = 85
    TRANSKV = 86
    TRANSKI = 87
    RESET = 253


class ArgType(IntEnum):
    """The byte before a command's argument (ArRobotPacketSender.h: INTARG, NINTARG, STRARG)."""

    INT = 0x3B
    NEG_INT = 0x1B
    STR = 0x2B


# HOSTBAUD/AUX1BAUD/AUX2BAUD argument codes.
BAUD_CODES = {9600: 0, 19200: 1, 38400: 2, 57600: 3, 115200: 4}

# Robot-to-client packet types.
SIP_TYPES = frozenset(range(0x30, 0x35))  # ARIA: 0x32 stopped / 0x33 moving; ROS-p2os: 0x30-0x34
SIP_STOPPED = 0x32
SIP_MOVING = 0x33
CONFIG_PAC = 0x20
ENCODER_PAC = 0x90


def command(cmd: int, arg: int | str | bytes | None = None) -> bytes:
    """The framed packet for ``cmd`` with an optional int (|arg| <= 65535) or string argument.

    >>> command(Command.VEL, -200).hex(" ")
    'fa fb 06 0b 1b c8 00 d3 1b'
    """
    if not 0 <= cmd <= 255:
        raise ValueError(f"a P2OS command number is one byte, not {cmd}")
    if arg is None:
        return frame(bytes((cmd,)))
    if isinstance(arg, int):
        mag = abs(arg)
        if mag > 0xFFFF:
            raise ValueError(f"a P2OS integer argument is 16 bits; {arg} does not fit")
        kind = ArgType.NEG_INT if arg < 0 else ArgType.INT
        return frame(bytes((cmd, kind, mag & 0xFF, mag >> 8)))
    raw = arg.encode("latin-1") if isinstance(arg, str) else bytes(arg)
    if len(raw) > 195:
        raise ValueError(f"a P2OS string argument has at most 195 bytes, not {len(raw)}")
    return frame(bytes((cmd, ArgType.STR, len(raw))) + raw)


def vel2_arg(left_units: int, right_units: int) -> int:
    """The VEL2 integer argument as ARIA sends it: left byte high, right byte low, read as a signed
    16-bit value (so :func:`command` sends ``0x1B`` + absolute value when the left byte is negative).

    ``left_units``/``right_units`` are wheel speeds in Vel2Divisor units (20 mm/s on a P2DX), -128..127.
    """
    for v in (left_units, right_units):
        if not -128 <= v <= 127:
            raise ValueError(f"VEL2 wheel speeds are signed bytes (-128..127 units), not {v}")
    raw = ((left_units & 0xFF) << 8) | (right_units & 0xFF)
    return raw - 0x10000 if raw & 0x8000 else raw


def vel2_wheels(value: int) -> tuple[int, int]:
    """(left, right) signed wheel units from a VEL2 argument in either encoding (ARIA's signed value,
    or Player's raw two's complement sent as a positive integer); MobileSim does the same."""
    value &= 0xFFFF
    right, left = value & 0xFF, value >> 8
    return (left - 256 if left & 0x80 else left), (right - 256 if right & 0x80 else right)


@dataclass(frozen=True, slots=True)
class CommandPacket:
    """A client command as a robot reads it. ``arg_type`` is None for a bare command; ``value`` the
    signed integer (None if absent or cut short); ``text`` the string argument's bytes."""

    cmd: int
    arg_type: int | None = None
    value: int | None = None
    text: bytes | None = None

    def int_or(self, default: int) -> int:
        return default if self.value is None else self.value


def parse_command(packet: Packet) -> CommandPacket:
    """Read a client packet leniently, as a P2OS robot must (spec §1.2, §1.11).

    Missing bytes give None rather than an error; a string may carry one extra trailing NUL; an
    unknown argument type byte is kept in ``arg_type`` with no value.
    """
    d = packet.data
    if len(d) < 2:
        return CommandPacket(d[0])
    kind = d[1]
    if kind in (ArgType.INT, ArgType.NEG_INT):
        if len(d) < 4:
            return CommandPacket(d[0], kind)
        mag = d[2] | d[3] << 8
        return CommandPacket(d[0], kind, -mag if kind == ArgType.NEG_INT else mag)
    if kind == ArgType.STR and len(d) >= 3:
        return CommandPacket(d[0], kind, text=bytes(d[3 : 3 + d[2]]))
    return CommandPacket(d[0], kind)


def cstrings(raw: bytes, count: int) -> list[str]:
    """``count`` NUL-terminated strings from ``raw`` (missing ones are ""), decoded as Latin-1."""
    parts = bytes(raw).split(b"\0")
    parts += [b""] * (count - len(parts))
    return [p.decode("latin-1") for p in parts[:count]]


def sync2_reply(name: str, robot_class: str, subclass: str) -> bytes:
    """The robot's framed SYNC2 reply: packet type 2, then three NUL-terminated strings."""
    body = b"".join(s.encode("latin-1") + b"\0" for s in (name, robot_class, subclass))
    return frame(b"\x02" + body)
