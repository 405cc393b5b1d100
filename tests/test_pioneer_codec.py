"""P2OS framing, checksum, arguments and the incremental reader (spec p2os.md §1.1-§1.4)."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pioneer.commands import (
    ArgType,
    Command,
    command,
    cstrings,
    parse_command,
    sync2_reply,
    vel2_arg,
    vel2_wheels,
)
from pioneer.packet import MAX_COUNT, Packet, PacketReader, checksum, frame

# Spec §1.1 worked examples: (what, bytes built by our codec, bytes in the spec).
WORKED = [
    ("SYNC0 / PULSE", command(Command.SYNC0), "fa fb 03 00 00 00"),
    ("SYNC1 / OPEN", command(Command.SYNC1), "fa fb 03 01 00 01"),
    ("SYNC2 / CLOSE", command(Command.SYNC2), "fa fb 03 02 00 02"),
    ("ENABLE 1", command(Command.ENABLE, 1), "fa fb 06 04 3b 01 00 05 3b"),
    ("ENABLE 0", command(Command.ENABLE, 0), "fa fb 06 04 3b 00 00 04 3b"),
    ("OPEN 1", command(Command.OPEN, 1), "fa fb 06 01 3b 01 00 02 3b"),
    ("CLOSE 1", command(Command.CLOSE, 1), "fa fb 06 02 3b 01 00 03 3b"),
    ("SONAR 1", command(Command.SONAR, 1), "fa fb 06 1c 3b 01 00 1d 3b"),
    ("VEL 200", command(Command.VEL, 200), "fa fb 06 0b 3b c8 00 d3 3b"),
    ("VEL -200", command(Command.VEL, -200), "fa fb 06 0b 1b c8 00 d3 1b"),
    ("RVEL 10", command(Command.RVEL, 10), "fa fb 06 15 3b 0a 00 1f 3b"),
    ("RVEL -10", command(Command.RVEL, -10), "fa fb 06 15 1b 0a 00 1f 1b"),
    ("SETV 2200", command(Command.SETV, 2200), "fa fb 06 06 3b 98 08 9e 43"),
    ("SETRV 500", command(Command.SETRV, 500), "fa fb 06 0a 3b f4 01 fe 3c"),
    ("CONFIG 1", command(Command.CONFIG, 1), "fa fb 06 12 3b 01 00 13 3b"),
    ("STOP", command(Command.STOP), "fa fb 03 1d 00 1d"),
    ("E_STOP", command(Command.E_STOP), "fa fb 03 37 00 37"),
    ("HOSTBAUD 2", command(Command.HOSTBAUD, 2), "fa fb 06 32 3b 02 00 34 3b"),
]


@pytest.mark.parametrize(("what", "built", "spec"), WORKED, ids=[w[0] for w in WORKED])
def test_worked_examples_of_spec_1_1_are_built_byte_for_byte(what, built, spec):
    assert built.hex(" ") == spec


@pytest.mark.parametrize(("what", "built", "spec"), WORKED, ids=[w[0] for w in WORKED])
def test_worked_examples_are_read_back_as_one_intact_packet(what, built, spec):
    reader = PacketReader()
    (pkt,) = reader.feed(bytes.fromhex(spec))
    assert pkt.to_bytes() == bytes.fromhex(spec)
    assert reader.bytes_skipped == 0


def test_checksum_adds_big_endian_pairs_and_xors_an_odd_last_byte():
    assert checksum(bytes([0x0B, 0x3B, 0xC8, 0x00])) == 0x0B3B + 0xC800
    assert checksum(bytes([0x04, 0x3B, 0x01])) == (0x043B) ^ 0x01
    assert checksum(b"\xff\xff\xff\xff") == 0xFFFE  # the sum wraps at 16 bits


def test_checksum_is_sent_high_byte_first():
    pkt = frame(bytes([0x06, 0x3B, 0x98, 0x08]))  # SETV 2200: 0x063B + 0x9808 = 0x9E43
    assert pkt[-2:] == b"\x9e\x43"


def test_sync2_reply_for_mockbot_matches_spec_1_3():
    assert sync2_reply("MockBot", "Pioneer", "p2dx").hex(" ") == (
        "fa fb 18 02 4d 6f 63 6b 42 6f 74 00 50 69 6f 6e 65 65 72 00 70 32 64 78 00 34 d0"
    )
    (pkt,) = PacketReader().feed(sync2_reply("MockBot", "Pioneer", "p2dx"))
    assert cstrings(pkt.payload, 3) == ["MockBot", "Pioneer", "p2dx"]


def test_negative_integer_is_sent_as_0x1b_and_its_absolute_value():
    assert parse_command(Packet(bytes.fromhex("0b1bc800"))).value == -200
    assert parse_command(Packet(bytes.fromhex("0b3bc800"))).value == 200


def test_string_argument_is_length_prefixed_and_a_trailing_nul_is_tolerated():
    aria = Packet(bytes([Command.SAY, ArgType.STR, 3]) + b"abc\0")  # ARIA comStr adds the NUL
    assert parse_command(aria).text == b"abc"
    assert command(Command.TTY2, "hi").hex(" ") == frame(bytes([42, 0x2B, 2]) + b"hi").hex(" ")


def test_seto_without_integer_bytes_as_ros_p2os_sends_it_is_read_without_value():
    parsed = parse_command(Packet(bytes.fromhex("073b")))
    assert (parsed.cmd, parsed.arg_type, parsed.value) == (Command.SETO, ArgType.INT, None)


def test_bare_command_has_no_argument():
    assert parse_command(Packet(b"\x01")) == parse_command(Packet(b"\x01"))
    assert parse_command(Packet(b"\x01")).arg_type is None


@given(st.integers(-128, 127), st.integers(-128, 127))
def test_vel2_aria_and_player_encodings_give_the_same_wheels(left, right):
    aria = vel2_arg(left, right)  # signed 16-bit, sent as 0x1B + abs when negative
    player = ((left & 0xFF) << 8) | (right & 0xFF)  # raw two's complement, always 0x3B
    for pkt in (command(Command.VEL2, aria), command(Command.VEL2, player)):
        (p,) = PacketReader().feed(pkt)
        assert vel2_wheels(parse_command(p).value) == (left, right)


def test_integer_argument_out_of_16_bits_is_refused():
    with pytest.raises(ValueError, match="16 bits"):
        command(Command.VEL, 70000)


# --- the incremental reader -------------------------------------------------------------------------

def test_reader_skips_aria_wms2_prefix_and_counts_it():
    reader = PacketReader()
    got = reader.feed(b"WMS2\r" + command(Command.SYNC0))
    assert [p.type for p in got] == [0]
    assert reader.bytes_skipped == 5


def test_reader_delivers_a_packet_split_across_feeds():
    pkt = command(Command.VEL, 200)
    reader = PacketReader()
    assert [r for b in pkt[:-1] for r in reader.feed(bytes([b]))] == []
    assert reader.feed(pkt[-1:]) == [Packet(pkt[3:-2])]


def test_reader_counts_and_skips_a_bad_checksum_then_finds_the_next_packet():
    bad = bytearray(command(Command.VEL, 200))
    bad[-1] ^= 0xFF
    reader = PacketReader()
    got = reader.feed(bytes(bad) + command(Command.STOP))
    assert [p.type for p in got] == [Command.STOP]
    assert reader.bad_checksums == 1
    assert reader.packets_ok == 1


@pytest.mark.parametrize("count", [0, 1, 2, MAX_COUNT + 1, 255])
def test_reader_rejects_impossible_byte_counts(count):
    reader = PacketReader()
    got = reader.feed(bytes([0xFA, 0xFB, count]) + command(Command.PULSE))
    assert [p.type for p in got] == [Command.PULSE]
    assert reader.bad_counts == 1


def test_reader_keeps_a_trailing_fa_that_may_start_the_next_header():
    pkt = command(Command.STOP)
    reader = PacketReader()
    assert reader.feed(b"xx" + pkt[:1]) == []
    assert [p.type for p in reader.feed(pkt[1:])] == [Command.STOP]


_packets = st.lists(st.binary(min_size=1, max_size=40).map(frame), min_size=1, max_size=8)
# Damage made of bytes other than the header's: the one thing no framer can survive is damage that
# happens to form a packet with a valid checksum ending inside the next intact one (a 1 in 65536
# coincidence per damaged header, which hypothesis would build on purpose from FA FB bytes).
_noise = st.binary(max_size=40).map(lambda b: b.replace(b"\xfa", b"\x5a").replace(b"\xfb", b"\x5b"))
_damaged = st.lists(_noise.filter(bool).map(frame), min_size=1, max_size=8)
# Garbage: noise with stray and fake headers (FA FB + a count) among it.
_garbage = st.lists(st.one_of(_noise, st.sampled_from([b"\xfa", b"\xfa\xfb", b"\xfa\xfb\x05"])),
                    max_size=10).map(b"".join)
_FLUSH = b"\x00" * (MAX_COUNT + 3)  # enough bytes for any header the damage left open to complete


def _chunked(data: bytes, cuts: list[int]):
    edges = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    return [data[a:b] for a, b in itertools.pairwise(edges)]


@settings(max_examples=200, deadline=None)
@given(garbage=_garbage, packets=_packets, cuts=st.lists(st.integers(0, 10_000), max_size=10))
def test_reader_after_random_garbage_delivers_every_following_packet(garbage, packets, cuts):
    reader = PacketReader()
    got = []
    for chunk in _chunked(garbage + b"".join(packets) + _FLUSH, cuts):
        got += reader.feed(chunk)
    assert [p.to_bytes() for p in got[len(got) - len(packets):]] == packets


@settings(max_examples=200, deadline=None)
@given(damaged=_damaged, packets=_packets,
       flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 7)), min_size=1, max_size=5))
def test_reader_after_bit_flips_delivers_every_following_intact_packet(damaged, packets, flips):
    bad = bytearray(b"".join(damaged))
    for pos, bit in flips:
        bad[pos % len(bad)] ^= 1 << bit
    reader = PacketReader()
    got = reader.feed(bytes(bad) + b"".join(packets) + _FLUSH)
    assert [p.to_bytes() for p in got[len(got) - len(packets):]] == packets


@settings(max_examples=200, deadline=None)
@given(damaged=_damaged, packets=_packets, cut=st.integers(1, 10_000))
def test_reader_after_a_truncated_packet_delivers_every_following_packet(damaged, packets, cut):
    stream = b"".join(damaged)
    stream = stream[: -(1 + cut % len(stream))]  # at least the last byte of the damaged run is missing
    reader = PacketReader()
    got = reader.feed(stream + b"".join(packets) + _FLUSH)
    assert [p.to_bytes() for p in got[len(got) - len(packets):]] == packets
    assert reader.pending == 0


def test_a_stalled_bogus_header_is_expired_and_the_packets_it_swallowed_are_delivered():
    r = PacketReader()
    sync0 = frame(bytes([0]))
    assert r.feed(b"\xfa\xfb\xc8\x01" + sync0 + sync0) == []  # waiting for 200 bytes that never come
    assert r.pending == 4 + 2 * len(sync0)
    assert [p.to_bytes() for p in r.expire()] == [sync0, sync0]
    assert r.pending == 0 and r.counters()["stalled"] >= 1
    assert r.expire() == []
