"""SIP, CONFIGpac and ENCODERpac decoding (spec §1.5, §1.6) and odometry from SIPs (§1.7, §1.8)."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pioneer.errors import ProtocolError
from pioneer.odometry import OdometryIntegrator, wrap15
from pioneer.packet import PacketReader, frame
from pioneer.params import P2DX
from pioneer.sip import (
    CONFIG_LAYOUT,
    SIP,
    EncoderCounts,
    RobotConfig,
    decode_config,
    decode_encoder,
    decode_sip,
    encode_config,
    encode_encoder,
    encode_sip,
)

# Spec §1.5: ARIA decoded both as battery 12.1 V, motors enabled, sonar 0 = 1000 units = 268 mm.
SIP_N1 = "fa fb 1e 32 00 00 00 00 00 00 00 00 00 00 79 00 00 00 00 01 00 00 01 00 e8 03 00 05 00 00 00 3c 62"
SIP_N0 = "fa fb 1b 32 00 00 00 00 00 00 00 00 00 00 79 00 00 00 00 01 00 00 00 00 05 00 00 00 33 7e"


def _read_one(hexbytes: str) -> SIP:
    (pkt,) = PacketReader().feed(bytes.fromhex(hexbytes))
    return decode_sip(pkt.data)


def test_sip_with_one_sonar_reading_decodes_as_aria_did():
    s = _read_one(SIP_N1)
    assert s.battery_volts == pytest.approx(12.1)
    assert s.motors_enabled
    assert s.sonar == ((0, 1000),)
    assert s.sonar_mm(P2DX.range_conv) == {0: pytest.approx(268.0)}
    assert (s.moving, s.xpos, s.ypos, s.thpos, s.grip_state, s.anport) == (False, 0, 0, 0, 0, 5)
    assert s.battery_x10 is None and s.flags3 is None


def test_sip_without_sonar_readings_decodes_as_aria_did():
    s = _read_one(SIP_N0)
    assert (s.battery_volts, s.motors_enabled, s.sonar) == (pytest.approx(12.1), True, ())


@pytest.mark.parametrize("hexbytes", [SIP_N1, SIP_N0])
def test_spec_sips_are_encoded_byte_for_byte(hexbytes):
    assert frame(encode_sip(_read_one(hexbytes))).hex(" ") == hexbytes


def test_stall_word_low_byte_is_left_stall_and_rear_bumpers_high_byte_right_stall_and_front():
    data = bytearray(bytes.fromhex(SIP_N0)[3:-2])
    data[12], data[13] = 0b0000_0111, 0b1000_0000  # left stall, rear bumpers 1+2; front bumper 7
    s = decode_sip(bytes(data))
    assert (s.left_stall, s.rear_bumpers, s.right_stall, s.front_bumpers) == (True, 0b11, False, 0b100_0000)


@pytest.mark.parametrize(
    ("bit", "prop"),
    [(0, "motors_enabled"), (5, "e_stop"), (6, "e_stall"), (9, "joystick_button"),
     (10, "charger_power_good")],
)
def test_flags_bits_are_named(bit, prop):
    assert getattr(SIP(flags=1 << bit), prop)
    assert not getattr(SIP(flags=0xFFFF ^ (1 << bit)), prop)


def test_flags_sonar_arrays_and_ledge_irs():
    assert SIP(flags=0b1_1000_1010).sonar_arrays == (True, False, True, False)
    assert SIP(flags=0x180).ledge_irs == (True, True)


def test_type_0x33_means_moving():
    data = bytearray(bytes.fromhex(SIP_N0)[3:-2])
    data[0] = 0x33
    assert decode_sip(bytes(data)).moving


def test_sip_shorter_than_its_sonar_count_is_a_protocol_error():
    data = bytearray(bytes.fromhex(SIP_N1)[3:-2])
    data[19] = 5  # claims 5 readings
    with pytest.raises(ProtocolError, match="at least 40 data bytes"):
        decode_sip(bytes(data))


def test_later_firmware_fields_are_read_while_bytes_remain():
    later = (123).to_bytes(2, "little") + b"\x02" + (-450).to_bytes(2, "little", signed=True)
    data = bytes.fromhex(SIP_N0)[3:-2] + later
    s = decode_sip(data)
    assert (s.battery_x10, s.charge_state, s.rot_vel, s.fault_flags) == (123, 2, -450, None)
    assert s.battery_volts == pytest.approx(12.3)


_u16, _i16, _u8 = st.integers(0, 0xFFFF), st.integers(-0x8000, 0x7FFF), st.integers(0, 255)
_optional = [_u16, _u8, _i16, _u16, _i16, st.integers(-128, 127), st.integers(-128, 127),
             st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1)]
_OPTIONAL_NAMES = ["battery_x10", "charge_state", "rot_vel", "fault_flags", "lat_vel", "temperature", "soc",
                   "uc_time", "flags3"]


@st.composite
def sips(draw):
    k = draw(st.integers(0, len(_OPTIONAL_NAMES)))  # later-firmware fields come as a prefix
    extra = {name: draw(strat) for name, strat in zip(_OPTIONAL_NAMES[:k], _optional[:k], strict=True)}
    return SIP(
        moving=draw(st.booleans()), xpos=draw(st.integers(0, 0x7FFF)), ypos=draw(st.integers(0, 0x7FFF)),
        thpos=draw(_i16), left_vel=draw(_i16), right_vel=draw(_i16), battery=draw(_u8),
        left_stall=draw(st.booleans()), right_stall=draw(st.booleans()),
        rear_bumpers=draw(st.integers(0, 127)), front_bumpers=draw(st.integers(0, 127)),
        control=draw(_i16), flags=draw(_u16), compass=draw(_u8),
        sonar=tuple(draw(st.lists(st.tuples(_u8, _u16), max_size=16))),
        grip_state=draw(_u8), anport=draw(_u8), analog=draw(_u8), digin=draw(_u8), digout=draw(_u8),
        **extra,
    )


@settings(max_examples=200, deadline=None)
@given(sips())
def test_sip_decode_inverts_encode(s):
    assert decode_sip(encode_sip(s)) == s


def test_sip_optional_field_gap_cannot_be_encoded():
    with pytest.raises(ValueError, match="battery_x10"):
        encode_sip(SIP(rot_vel=5))


def test_config_layout_names_every_robotconfig_field():
    assert [f.name for f in fields(RobotConfig)] == [name for name, _ in CONFIG_LAYOUT]


def test_config_packet_round_trips_and_stops_where_old_firmware_stops():
    cfg = RobotConfig(robot_type="Pioneer", subtype="p2dx", serial_number="42", reserved=0,
                      rot_vel_top=500, trans_vel_top=2200, rot_accel_top=300, trans_accel_top=1000,
                      pwm_max=1000, name="robbie", sip_cycle=100, host_baud=0, aux1_baud=0, has_gripper=0,
                      front_sonar=1, rear_sonar=1)
    data = encode_config(cfg)
    assert data[0] == 0x20
    assert decode_config(data) == cfg
    assert decode_config(data).low_battery is None


def test_config_decoding_tolerates_a_packet_cut_mid_field():
    data = encode_config(RobotConfig(robot_type="Pioneer", subtype="p2dx", rot_vel_top=500))
    assert decode_config(data[:-1]).rot_vel_top is None


def test_encoder_packet_is_two_little_endian_int32():
    data = bytes([0x90]) + (-5).to_bytes(4, "little", signed=True) + (70000).to_bytes(4, "little")
    assert decode_encoder(data) == EncoderCounts(-5, 70000)
    assert encode_encoder(EncoderCounts(-5, 70000)) == data


# --- odometry from SIPs -----------------------------------------------------------------------------

@pytest.mark.parametrize(("old", "new", "delta"),
                         [(0x7FF0, 0x0010, 0x20), (0x0010, 0x7FF0, -0x20), (5, 9, 4)])
def test_position_difference_wraps_at_15_bits(old, new, delta):
    assert wrap15(new - old) == delta


def _sips_along(xs, ths=None):
    ths = ths or [0] * len(xs)
    return [SIP(xpos=x & 0x7FFF, thpos=th) for x, th in zip(xs, ths, strict=True)]


def test_odometry_crosses_the_15_bit_boundary_forward_and_back():
    integ = OdometryIntegrator(P2DX)
    xs = [0x7F00, 0x7FC0, 0x8040, 0x8100, 0x7FC0, 0x7F00]  # raw values beyond 0x7FFF wrap in the SIP
    got = [integ.update(s, t).x for t, s in enumerate(_sips_along(xs))]
    expected = [(x - 0x7F00) * 0.84 / 1000 for x in xs]
    assert got == pytest.approx(expected)


def test_odometry_origin_is_the_pose_at_the_first_sip_in_its_heading():
    integ = OdometryIntegrator(P2DX)
    integ.update(SIP(xpos=1000, ypos=1000, thpos=1024), 0.0)  # robot faces +y of its own frame
    odo = integ.update(SIP(xpos=1000, ypos=1000 + 100, thpos=1024), 0.1)
    assert (odo.x, odo.y, odo.theta) == pytest.approx((0.084, 0.0, 0.0))


def test_heading_unwraps_through_plus_minus_pi_and_is_reported_in_minus_pi_pi():
    integ = OdometryIntegrator(P2DX)
    ths = [0, 1000, 2000, -2000, -1000, 0, 1000]  # one full counter-clockwise turn and a quarter
    out = [integ.update(s, t) for t, s in enumerate(_sips_along([0] * len(ths), ths))]
    assert out[3].theta == pytest.approx(2096 * 2 * math.pi / 4096 - 2 * math.pi)
    assert out[-1].theta == pytest.approx(1000 * 2 * math.pi / 4096)


def test_velocities_from_wheels_follow_diffconvfactor():
    odo = OdometryIntegrator(P2DX).update(SIP(left_vel=100, right_vel=300), 0.0)
    assert (odo.v, odo.left, odo.right) == pytest.approx((0.2, 0.1, 0.3))
    assert odo.w == pytest.approx((300 - 100) / 2 * 0.0056)


def test_rotvel_field_is_preferred_when_the_firmware_sends_it():
    s = SIP(left_vel=100, right_vel=300, battery_x10=125, charge_state=0, rot_vel=-900)
    assert OdometryIntegrator(P2DX).update(s, 0.0).w == pytest.approx(math.radians(-90))


def test_rebase_continues_the_pose_from_a_new_robot_session():
    integ = OdometryIntegrator(replace(P2DX))
    integ.update(SIP(xpos=0), 0)
    integ.update(SIP(xpos=1000), 1)
    integ.rebase()  # the robot was reset: its position restarts anywhere
    integ.update(SIP(xpos=20000, thpos=2047), 2)
    odo = integ.update(SIP(xpos=20000 - 100, thpos=2047), 3)  # it moved 100 units along its own -x
    assert odo.x == pytest.approx(0.84 + 0.084, abs=1e-4)
