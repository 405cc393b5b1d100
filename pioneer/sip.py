"""Robot-to-client packets: the standard SIP (spec §1.5), CONFIGpac (§1.6) and ENCODERpac (§1.6).

Values stay in P2OS units here (exactly what is on the wire, so ``decode_sip(encode_sip(s)) == s``);
properties and :mod:`pioneer.odometry` convert to SI with a :class:`~pioneer.params.RobotParams`.
Every function takes and returns the packet's *data* (type byte first, no header, no checksum):
frame them with :func:`pioneer.packet.frame`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field, make_dataclass

from pioneer.commands import CONFIG_PAC, ENCODER_PAC, SIP_MOVING, SIP_STOPPED, SIP_TYPES
from pioneer.errors import ProtocolError

# type, XPOS, YPOS, THPOS, L VEL, R VEL, BATTERY, STALL lo, STALL hi, CONTROL, FLAGS, COMPASS, SONAR n
_HEAD = struct.Struct("<BHHhhhBBBhHBB")
_SONAR = struct.Struct("<BH")
_TAIL = struct.Struct("<BBBBB")  # GRIP_STATE, ANPORT, ANALOG, DIGIN, DIGOUT
# Later-firmware fields, each present only if the packet is long enough for it (ARIA reads each one
# only while bytes remain), in wire order.
_OPTIONAL = (
    ("battery_x10", struct.Struct("<H")),
    ("charge_state", struct.Struct("<B")),
    ("rot_vel", struct.Struct("<h")),
    ("fault_flags", struct.Struct("<H")),
    ("lat_vel", struct.Struct("<h")),
    ("temperature", struct.Struct("<b")),
    ("soc", struct.Struct("<b")),
    ("uc_time", struct.Struct("<I")),
    ("flags3", struct.Struct("<I")),
)


def _flag(mask: int, doc: str) -> property:
    return property(lambda self: bool(self.flags & mask), doc=doc)


@dataclass(frozen=True)
class SIP:
    """A standard server information packet, in wire units.

    - ``xpos``/``ypos``: the 15 valid bits of the robot's position, DistConvFactor mm per unit.
    - ``thpos``: heading, int16 in AngleConvFactor (2π/4096 rad) units.
    - ``left_vel``/``right_vel``: wheel speeds, VelConvFactor mm/s per unit.
    - ``battery``: volts × 10. ``control``: heading servo setpoint, angle units.
    - ``left_stall``/``right_stall``: wheel stall bits; ``rear_bumpers``/``front_bumpers``: 7 bits each
      (bits 1-7 of the STALL word's low/high byte).
    - ``flags``: the FLAGS word (see the properties). ``compass``: 2° units.
    - ``sonar``: the new readings ``(number, range)``, range in RangeConvFactor mm units.
    - ``grip_state``, ``anport`` (low, high byte of the "timer" word, ARIA/ARCOS order), ``analog``
      (0-255 = 0-5 V), ``digin``, ``digout``.
    - later firmware, None when absent: ``battery_x10`` (0.1 V), ``charge_state``, ``rot_vel``
      (0.1 deg/s), ``fault_flags``, ``lat_vel`` (mm/s), ``temperature`` (°C), ``soc`` (%),
      ``uc_time`` (ms), ``flags3``.
    """

    moving: bool = False
    xpos: int = 0
    ypos: int = 0
    thpos: int = 0
    left_vel: int = 0
    right_vel: int = 0
    battery: int = 0
    left_stall: bool = False
    right_stall: bool = False
    rear_bumpers: int = 0
    front_bumpers: int = 0
    control: int = 0
    flags: int = 0
    compass: int = 0
    sonar: tuple[tuple[int, int], ...] = ()
    grip_state: int = 0
    anport: int = 0
    analog: int = 0
    digin: int = 0
    digout: int = 0
    battery_x10: int | None = None
    charge_state: int | None = None
    rot_vel: int | None = None
    fault_flags: int | None = None
    lat_vel: int | None = None
    temperature: int | None = None
    soc: int | None = None
    uc_time: int | None = None
    flags3: int | None = None

    @property
    def battery_volts(self) -> float:
        """Battery voltage in volts (the finer BATTERYX10 when the firmware sends it)."""
        return (self.battery_x10 if self.battery_x10 is not None else self.battery) / 10.0

    motors_enabled = _flag(0x0001, "The motors are enabled (FLAGS bit 0).")
    e_stop = _flag(0x0020, "The STOP / emergency-stop button is pressed (FLAGS bit 5).")
    e_stall = _flag(0x0040, "E_STALL: a stall stops the robot (FLAGS bit 6).")
    joystick_button = _flag(0x0200, "The joystick button is pressed (FLAGS bit 9).")
    charger_power_good = _flag(0x0400, "The charger's power is good (FLAGS bit 10).")

    @property
    def sonar_arrays(self) -> tuple[bool, bool, bool, bool]:
        """Sonar arrays 1-4 enabled (FLAGS bits 1-4)."""
        f = self.flags
        return bool(f & 0x02), bool(f & 0x04), bool(f & 0x08), bool(f & 0x10)

    @property
    def ledge_irs(self) -> tuple[bool, bool]:
        """Left and right ledge IR sensors triggered (FLAGS bits 7, 8)."""
        return bool(self.flags & 0x80), bool(self.flags & 0x100)

    def sonar_mm(self, range_conv: float) -> dict[int, float]:
        """This SIP's sonar readings in mm by transducer number (RangeConvFactor ``range_conv``)."""
        return {num: rng * range_conv for num, rng in self.sonar}


_NO_OPTIONAL = (None,) * len(_OPTIONAL)


def _optional_fields(data: bytes, off: int) -> tuple:
    """The later-firmware fields from ``off`` on, each only if the packet still holds it."""
    values = []
    for _, st in _OPTIONAL:
        if len(data) - off < st.size:
            break
        values.append(st.unpack_from(data, off)[0])
        off += st.size
    return (*values, *_NO_OPTIONAL[len(values) :])


def decode_sip(data: bytes) -> SIP:
    """Decode a standard SIP's data (type byte 0x30-0x34 first). Raises :class:`ProtocolError`
    when the packet is shorter than its sonar count says (a SIP has at least 25 + 3n data bytes)."""
    size = len(data)
    if size < 25 or data[0] not in SIP_TYPES:
        raise ProtocolError(
            f"expected a SIP (type 0x32/0x33, at least 25 data bytes), got type "
            f"0x{data[0] if data else 0:02x} with {size} bytes"
        )
    (kind, x, y, th, lv, rv, batt, stall_lo, stall_hi, control, flags, compass, n) = _HEAD.unpack_from(data)
    end = 25 + 3 * n
    if size < end:
        raise ProtocolError(f"a SIP with {n} sonar readings has at least {end} data bytes, got {size}")
    sonar = tuple(_SONAR.iter_unpack(data[20 : end - 5])) if n else ()
    grip, anport, analog, digin, digout = _TAIL.unpack_from(data, end - 5)
    bx10, charge, rotvel, faults, latvel, temp, soc, uctime, flags3 = (
        _optional_fields(data, end) if size > end else _NO_OPTIONAL
    )
    # The driver's hot path: the instance's __dict__ is built as one dict display and set directly,
    # rather than by ~30 object.__setattr__ calls in the frozen dataclass's __init__ (3x faster;
    # the same frozen object: eq, hash and repr as usual).
    sip = object.__new__(SIP)
    object.__setattr__(sip, "__dict__", {
        "moving": kind == SIP_MOVING, "xpos": x & 0x7FFF, "ypos": y & 0x7FFF, "thpos": th,
        "left_vel": lv, "right_vel": rv, "battery": batt,
        "left_stall": (stall_lo & 1) == 1, "right_stall": (stall_hi & 1) == 1,
        "rear_bumpers": stall_lo >> 1, "front_bumpers": stall_hi >> 1, "control": control, "flags": flags,
        "compass": compass, "sonar": sonar, "grip_state": grip, "anport": anport, "analog": analog,
        "digin": digin, "digout": digout, "battery_x10": bx10, "charge_state": charge, "rot_vel": rotvel,
        "fault_flags": faults, "lat_vel": latvel, "temperature": temp, "soc": soc, "uc_time": uctime,
        "flags3": flags3,
    })
    return sip


def encode_sip(s: SIP) -> bytes:
    """The data of a standard SIP (what a robot sends), the inverse of :func:`decode_sip`.

    Optional later-firmware fields are written in wire order up to the last one that is set; one
    left at None before a set one cannot be represented and raises ValueError.
    """
    parts = [
        _HEAD.pack(
            SIP_MOVING if s.moving else SIP_STOPPED, s.xpos & 0x7FFF, s.ypos & 0x7FFF, s.thpos,
            s.left_vel, s.right_vel, s.battery,
            (s.rear_bumpers << 1 | s.left_stall) & 0xFF, (s.front_bumpers << 1 | s.right_stall) & 0xFF,
            s.control, s.flags, s.compass, len(s.sonar),
        ),
        *(_SONAR.pack(num, rng) for num, rng in s.sonar),
        _TAIL.pack(s.grip_state, s.anport, s.analog, s.digin, s.digout),
    ]
    values = [getattr(s, name) for name, _ in _OPTIONAL]
    last = max((i for i, v in enumerate(values) if v is not None), default=-1)
    for (name, st), v in zip(_OPTIONAL[: last + 1], values, strict=False):
        if v is None:
            raise ValueError(f"SIP field {name} is None but a later optional field is set")
        parts.append(st.pack(v))
    return b"".join(parts)


# --- CONFIGpac (0x20) ---------------------------------------------------------------------------------
# ARIA's field order (ArRobotConfigPacketReader::packetHandler): "s" a NUL-terminated string,
# otherwise a struct code. Older firmware stops early; every field the packet does not reach is None.
CONFIG_LAYOUT: tuple[tuple[str, str], ...] = (
    ("robot_type", "s"), ("subtype", "s"), ("serial_number", "s"), ("reserved", "B"),
    ("rot_vel_top", "H"), ("trans_vel_top", "H"), ("rot_accel_top", "H"), ("trans_accel_top", "H"),
    ("pwm_max", "H"), ("name", "s"), ("sip_cycle", "B"), ("host_baud", "B"), ("aux1_baud", "B"),
    ("has_gripper", "H"), ("front_sonar", "H"), ("rear_sonar", "B"), ("low_battery", "H"),
    ("rev_count", "H"), ("watchdog", "H"), ("normal_mpacs", "B"), ("stall_val", "H"),
    ("stall_count", "H"), ("joy_vel", "H"), ("joy_rot_vel", "H"), ("rot_vel_max", "H"),
    ("trans_vel_max", "H"), ("rot_accel", "H"), ("rot_decel", "H"), ("rot_kp", "H"), ("rot_kv", "H"),
    ("rot_ki", "H"), ("trans_accel", "H"), ("trans_decel", "H"), ("trans_kp", "H"), ("trans_kv", "H"),
    ("trans_ki", "H"), ("front_bumps", "B"), ("rear_bumps", "B"), ("has_charger", "B"),
    ("sonar_cycle", "B"), ("reset_baud", "B"), ("gyro_type", "B"), ("drift_factor", "h"),
    ("aux2_baud", "B"), ("aux3_baud", "B"), ("ticks_mm", "H"), ("shutdown_voltage", "H"),
    ("firmware_version", "s"), ("gyro_cw", "H"), ("gyro_ccw", "H"), ("kinematics_delay", "B"),
    ("lat_vel_top", "H"), ("lat_accel_top", "H"), ("lat_vel_max", "H"), ("lat_accel", "H"),
    ("lat_decel", "H"), ("powerbot_charge_threshold", "H"), ("pdb_port", "B"), ("gyro_rate_limit", "H"),
    ("high_temperature_shutdown", "b"), ("power_bits", "H"), ("battery_type", "B"),
    ("state_of_charge_low", "H"), ("state_of_charge_shutdown", "H"),
    ("firmware_bootloader_version", "s"), ("config_flags", "I"), ("gyro_fw_version", "h"),
)

RobotConfig = make_dataclass(
    "RobotConfig",
    [(name, str | None if code == "s" else int | None, field(default=None)) for name, code in CONFIG_LAYOUT],
    frozen=True,
)
RobotConfig.__module__ = __name__
RobotConfig.__doc__ = (
    "A CONFIGpac (reply to CONFIG 1), fields in ARIA's order; None where the firmware stops early. "
    "Units as P2OS reports them: velocities mm/s and deg/s, accelerations mm/s² and deg/s², "
    "``sip_cycle`` ms, ``watchdog`` ms, ``low_battery``/``shutdown_voltage`` 0.1 V, bauds as HOSTBAUD "
    "codes; ``reset_baud`` 2 means the robot accepts HOSTBAUD."
)


def decode_config(data: bytes):
    """Decode a CONFIGpac's data (type byte 0x20 first) into a :class:`RobotConfig`."""
    if not data or data[0] != CONFIG_PAC:
        raise ProtocolError(f"expected a CONFIGpac (type 0x20), got type 0x{data[0] if data else 0:02x}")
    values: dict[str, object] = {}
    off, n = 1, len(data)
    for name, code in CONFIG_LAYOUT:
        if off >= n:
            break
        if code == "s":
            nul = data.find(b"\0", off)
            stop = n if nul < 0 else nul
            values[name] = bytes(data[off:stop]).decode("latin-1")
            off = stop + 1
        else:
            size = struct.calcsize("<" + code)
            if n - off < size:
                break
            values[name] = struct.unpack_from("<" + code, data, off)[0]
            off += size
    return RobotConfig(**values)


def encode_config(cfg) -> bytes:
    """A CONFIGpac's data for ``cfg``, up to its last field that is set (unset earlier ones as 0/"")."""
    values = [getattr(cfg, name) for name, _ in CONFIG_LAYOUT]
    last = max((i for i, v in enumerate(values) if v is not None), default=-1)
    out = bytearray((CONFIG_PAC,))
    for (_, code), v in zip(CONFIG_LAYOUT[: last + 1], values, strict=False):
        if code == "s":
            out += (v or "").encode("latin-1") + b"\0"
        else:
            out += struct.pack("<" + code, v or 0)
    return bytes(out)


# --- ENCODERpac (0x90) ---------------------------------------------------------------------------------
_ENCODER = struct.Struct("<Bii")


@dataclass(frozen=True, slots=True)
class EncoderCounts:
    """Raw wheel encoder counts (ticks) from an ENCODERpac, left then right, int32."""

    left: int
    right: int


def decode_encoder(data: bytes) -> EncoderCounts:
    if len(data) < _ENCODER.size or data[0] != ENCODER_PAC:
        got = bytes(data[:9]).hex(" ")
        raise ProtocolError(f"expected an ENCODERpac (type 0x90, 9 data bytes), got {got}")
    _, left, right = _ENCODER.unpack_from(data)
    return EncoderCounts(left, right)


def encode_encoder(e: EncoderCounts) -> bytes:
    return _ENCODER.pack(ENCODER_PAC, e.left, e.right)
