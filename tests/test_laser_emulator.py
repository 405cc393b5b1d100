"""The LMS2xx emulator answers real clients byte for byte: ARIA (spec §2.10), Player, sicktoolbox."""

from __future__ import annotations

import time

import numpy as np
import pytest
import serial

from laser.crc import crc16_reference
from laser.emulator import LMS2xxEmulator
from laser.telegram import NAK, FrameReader, reply
from laser.values import decode_b0


def frame(hexbytes: str) -> bytes:
    """A host telegram from its bytes without CRC, CRC computed by the literal algorithm."""
    body = bytes.fromhex(hexbytes)
    crc = crc16_reference(body)
    return body + bytes((crc & 0xFF, crc >> 8))


def ack_reply(hexdata: str) -> bytes:
    """ACK, then the reply telegram of ``hexdata`` (code + data) with status 0x10."""
    data = bytes.fromhex(hexdata)
    return b"\x06" + reply(data[0], data[1:])


@pytest.fixture
def client(pty_pair):
    """A raw pyserial client at 9600 baud and an emulator that powered on at 9600."""
    emu = LMS2xxEmulator(pty_pair.master, rate_limit=False, boot_time=0.05).start()
    ser = serial.Serial(pty_pair.path, 9600, timeout=1.0)
    yield ser, emu
    ser.close()
    emu.stop()


def send(ser: serial.Serial, data: bytes) -> bytes:
    """Write a request; return exactly the bytes of the answer: the ACK byte and one whole telegram
    (its length read from its own header), or what arrived before the timeout."""
    ser.write(data)
    got = ser.read(5)
    if len(got) < 5:
        return got
    return got + ser.read((got[3] | (got[4] << 8)) + 2)


def until(ser: serial.Serial, code: int, timeout: float = 1.0):
    """Read telegrams until one with ``code``; returns it."""
    r = FrameReader()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for tg in r.feed(ser.read(ser.in_waiting or 1)):
            if tg.command == code:
                return tg
    raise AssertionError(f"no 0x{code:02X} telegram")


def test_aria_laser_connect_sequence_of_spec_2_10(client):
    ser, emu = client
    # 1. reset at 9600: ACK, 91 10, then 90 "LMS200;30106;V02.10 " 10
    assert send(ser, frame("02 00 01 00 10")) == ack_reply("91")
    power_on = reply(0x90, b"LMS200;30106;V02.10 ")
    assert ser.read(len(power_on)) == power_on
    # 2. 20 40 at 9600; ARIA does not wait for the reply but it comes at 9600
    assert send(ser, frame("02 00 02 00 20 40")) == ack_reply("A0 00")
    time.sleep(0.02)
    ser.baudrate = 38400
    # 3. AriaCoda's resolution 0 (spec §2.9): "keep current", answered as 180 deg / 1 deg
    assert send(ser, frame("02 00 05 00 3b b4 00 00 00")) == ack_reply("BB 01 B4 00 64 00")
    # 4. installation mode
    assert send(ser, frame("02 00 0a 00 20 00 53 49 43 4b 5f 4c 4d 53")) == ack_reply("A0 00")
    # 5. ARIA's 33-byte 0x77 block: mm, mode 5 -> F7 01 + echo
    block = bytes.fromhex("00 00 46 00 00 05 01 00 00 02 02") + bytes(22)
    ser.write(frame("02 00 22 00 77 " + block.hex(" ")))
    assert ser.read(1) == b"\x06"
    f7 = until(ser, 0xF7)
    assert f7.data[0] == 1 and f7.data[1:34] == block and f7.status == 0x10
    # 6. continuous output: A0 00 10, then 0xB0 with count word 181 | 0x4000 (mm)
    assert send(ser, frame("02 00 02 00 20 24")) == ack_reply("A0 00")
    b0 = until(ser, 0xB0)
    assert b0.data[:2] == (181 | 0x4000).to_bytes(2, "little")
    scan = decode_b0(b0, mode=5)
    assert scan.count == 181 and np.degrees(scan.angles[[0, -1]]).tolist() == pytest.approx([-90, 90])
    # 7. disconnect: 20 25, 20 42, back to 9600
    ser.write(frame("02 00 02 00 20 25"))
    assert until(ser, 0xA0).data == b"\x00"
    ser.reset_input_buffer()
    assert send(ser, frame("02 00 02 00 20 42")) == ack_reply("A0 00")
    time.sleep(0.02)
    assert emu.baud == 9600 and not emu.streaming


def test_player_sicklms200_setup_sequence(client):
    ser, _emu = client

    def ask(hexbytes: str, code: int):
        ser.reset_input_buffer()  # Player calls tcflush(TCIOFLUSH) before every write
        ser.write(frame(hexbytes))
        return until(ser, code)

    assert send(ser, frame("02 00 02 00 20 25")) == ack_reply("A0 00")  # connect-rate probe
    assert ask("02 00 02 00 20 40", 0xA0).data == b"\x00"
    ser.baudrate = 38400
    assert ask("02 00 01 00 3a", 0xBA).data.startswith(b"LMS")
    assert ask("02 00 0a 00 20 00 " + b"SICK_LMS".hex(" "), 0xA0).data == b"\x00"
    b1 = ask("02 00 01 00 31", 0xB1)
    payload = bytes((0xB1,)) + b1.data
    assert len(payload) >= 111
    assert (
        int.from_bytes(payload[107:109], "little") == 180
        and int.from_bytes(payload[109:111], "little") == 100
    )
    assert ask("02 00 05 00 3b b4 00 32 00", 0xBB).data == bytes.fromhex("01 b4 00 32 00")
    f4 = ask("02 00 01 00 74", 0xF4)
    block8 = f4.data[0:4] + bytes((0x00, 0x00, 0x01))  # Player: availability, mode 0, mm
    f7 = ask("02 00 08 00 77 " + block8.hex(" "), 0xF7)
    assert f7.data[0] == 1
    assert ask("02 00 02 00 20 24", 0xA0).data == b"\x00"
    b0 = until(ser, 0xB0)
    assert b0.data[:2] == (361 | 0x4000).to_bytes(2, "little") and decode_b0(b0).count == 361


def test_sicktoolbox_initialize_sequence(client):
    ser, _emu = client
    assert send(ser, frame("02 00 02 00 20 40")) == ack_reply("A0 00")
    ser.baudrate = 38400
    for request, code in [("20 25", 0xA0), ("3a", 0xBA), ("31", 0xB1), ("74", 0xF4)]:
        body = bytes.fromhex(request)
        ser.write(frame(f"02 00 {len(body):02x} 00 {request}"))
        assert ser.read(1) == b"\x06"
        tg = until(ser, code)
        assert tg.status == 0x10 and tg.address == 0x80
    assert len(tg.data) == 34  # the config block as sicktoolbox's 0x77 writes it (35 with CMD)


def test_bad_crc_is_answered_with_nak(client):
    ser, emu = client
    good = frame("02 00 02 00 20 25")
    ser.timeout = 0.2
    assert send(ser, good[:-1] + bytes((good[-1] ^ 0x01,))) == bytes((NAK,))
    assert emu.counters["naks_sent"] == 1
    assert send(ser, good) == ack_reply("A0 00")  # and it still listens


def test_unknown_command_gets_ack_and_0x92(client):
    ser, _emu = client
    ser.write(frame("02 00 01 00 66"))
    assert ser.read(1) == b"\x06"
    assert until(ser, 0x92).data == b"\x66"


def test_traffic_at_another_baud_is_unintelligible(client):
    ser, emu = client
    ser.baudrate = 38400  # the device listens at 9600
    ser.timeout = 0.2
    assert send(ser, frame("02 00 02 00 20 25")) == b""
    assert emu.counters["bytes_dropped"] == 8 and not emu.counters["telegrams"]


def test_configuration_needs_installation_mode(client):
    ser, emu = client
    ser.write(frame("02 00 08 00 77 00 00 46 00 00 05 00"))
    assert until(ser, 0xF7).data[0] == 0
    assert emu.config.units == "mm"


def test_request_values_on_demand_and_units_follow_the_config(client):
    ser, _emu = client
    ser.write(frame("02 00 0a 00 20 00 " + b"SICK_LMS".hex(" ")))
    until(ser, 0xA0)
    ser.write(frame("02 00 08 00 77 00 00 46 00 00 00 00"))  # cm
    assert until(ser, 0xF7).data[0] == 1
    ser.write(frame("02 00 02 00 30 01"))
    b0 = until(ser, 0xB0)
    assert b0.data[:2] == (181).to_bytes(2, "little")  # bits 14-15 = 00: cm
    assert decode_b0(b0).ranges[0] == pytest.approx(2.0)


@pytest.mark.parametrize(("baud", "hz"), [(38400, 10.3), (500000, 75.0)])
def test_stream_rate_is_what_the_baud_and_mirror_allow(pty_pair, baud, hz):
    emu = LMS2xxEmulator(pty_pair.master, baud=baud, rate_limit=True).start()
    ser = serial.Serial(pty_pair.path, baud, timeout=0.5)
    try:
        ser.write(frame("02 00 02 00 20 24"))
        until(ser, 0xA0)
        first = emu.counters["scans_sent"]
        time.sleep(0.4)
        rate = (emu.counters["scans_sent"] - first) / 0.4
        assert rate == pytest.approx(hz, rel=0.3)
    finally:
        ser.close()
        emu.stop()
