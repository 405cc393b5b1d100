"""LMS2xx codec: CRC16 golden vectors (spec lms2xx.md §2.1), framing, resynchronisation, 0xB0 values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from laser import protocol as p
from laser.crc import MAX_CRC_SPAN, crc16, crc16_reference
from laser.telegram import ACK, NAK, FrameReader, Telegram, encode_telegram, reply, request
from laser.timing import b0_size, scan_period, transmit_time
from laser.values import decode_b0, encode_b0, make_scan, max_code

# Spec §2.1: every test vector, as written there (STX .. CRC_hi).
GOLDEN = [
    "02 00 02 00 20 24 34 08",
    "02 00 02 00 20 25 35 08",
    "02 00 02 00 20 40 50 08",
    "02 00 02 00 20 41 51 08",
    "02 00 02 00 20 42 52 08",
    "02 00 02 00 20 48 58 08",
    "02 00 01 00 10 34 12",
    "02 00 02 00 30 01 31 18",
    "02 00 05 00 3b b4 00 64 00 97 49",
    "02 00 05 00 3b b4 00 32 00 3b 1f",
    "02 00 05 00 3b 64 00 19 00 e7 72",
    "02 00 0a 00 20 00 53 49 43 4b 5f 4c 4d 53 be c5",
    "02 80 03 00 a0 00 10 16 0a",
]


@pytest.mark.parametrize("vector", GOLDEN)
def test_crc16_matches_every_spec_vector(vector):
    frame = bytes.fromhex(vector)
    expected = frame[-2] | (frame[-1] << 8)
    assert crc16_reference(frame[:-2]) == expected
    assert crc16(frame[:-2]) == expected


@pytest.mark.parametrize("vector", GOLDEN)
def test_encoder_reproduces_every_spec_vector(vector):
    frame = bytes.fromhex(vector)
    tg = FrameReader().feed(frame)[0]
    assert tg.encode() == frame


def test_request_builder_gives_the_quoted_continuous_output_telegram():
    assert request(p.SWITCH_MODE, p.CONTINUOUS) == bytes.fromhex("02 00 02 00 20 24 34 08")
    assert request(p.SWITCH_MODE, p.INSTALLATION, p.PASSWORD).hex(" ").endswith("be c5")
    assert reply(0xA0, b"\x00") == bytes.fromhex("02 80 03 00 a0 00 10 16 0a")


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=MAX_CRC_SPAN))
def test_table_crc_equals_the_literal_algorithm(data):
    assert crc16(data) == crc16_reference(data)


def test_reply_telegram_splits_status_from_data():
    tg = FrameReader().feed(bytes.fromhex("02 80 03 00 a0 00 10 16 0a"))[0]
    assert tg == Telegram(command=0xA0, data=b"\x00", address=0x80, status=0x10)
    assert tg.is_reply and tg.size == 9


def test_ack_nak_and_garbage_are_counted_as_skipped():
    r = FrameReader()
    out = r.feed(bytes((ACK, NAK, 0x55)) + request(0x20, 0x25))
    assert [t.command for t in out] == [0x20]
    assert (r.counters.acks, r.counters.naks, r.counters.bytes_skipped) == (1, 1, 3)


def test_oversize_length_is_rejected_and_search_continues():
    r = FrameReader()
    bogus = bytes((0x02, 0x00, 0x2D, 0x03))  # LEN 813 > 812
    assert [t.command for t in r.feed(bogus + request(0x31))] == [0x31]
    assert r.counters.oversize == 1


def test_bad_crc_restarts_the_search_at_the_byte_after_its_stx():
    good = request(0x20, 0x24)
    # A corrupted frame whose claimed body swallows a good telegram: the good one must survive.
    corrupted = bytes((0x02, 0x00, len(good) + 1, 0x00, 0x20)) + good + b"\x00\x00"
    r = FrameReader()
    assert [t.encode() for t in r.feed(corrupted)] == [good]
    assert r.counters.bad_crc == 1


def test_incomplete_noise_frame_does_not_stall_a_following_telegram():
    good = reply(0xA0, b"\x00")
    r = FrameReader()
    assert r.feed(b"\x02\x00\x00\x02" + good) == [FrameReader().feed(good)[0]]  # noise claims 512 bytes


def test_byte_by_byte_feeding_yields_each_telegram_once_with_its_position():
    stream = reply(0xA0, b"\x00") + bytes((ACK,)) + reply(0xBB, p.VariantReply(True, 180, 100).encode())
    r = FrameReader()
    got = [t for b in stream for t in r.feed(bytes((b,)))]
    assert [t.command for t in got] == [0xA0, 0xBB]
    assert FrameReader().feed_positions(stream + b"xyz")[-1][1] == 3


def test_payload_longer_than_812_cannot_be_encoded():
    with pytest.raises(ValueError, match="812"):
        encode_telegram(0xB0, bytes(812))


# ---- hypothesis: garbage, bit flips, truncation never raise; intact telegrams still arrive ----

_telegrams = st.builds(
    lambda cmd, data, status: encode_telegram(cmd, data, address=0x80, status=status),
    st.integers(0, 255),
    st.binary(max_size=60),
    st.integers(0, 255),
)


def _damaged(frame: bytes, how: int, pos: int, bit: int) -> bytes:
    if how == 0:
        return frame[: pos % len(frame)]  # truncated
    flipped = bytearray(frame)
    flipped[pos % len(frame)] ^= 1 << bit
    return bytes(flipped)


def _swallowed(stream: bytes, goods: list[tuple[int, bytes]]) -> bool:
    """Whether a frame with a good CRC starts at an STX of ``stream`` outside the good telegrams
    (``goods``: (offset, bytes)) and runs over the STX of one: a valid telegram holding its start."""
    inside = set()
    for at, g in goods:
        inside.update(range(at, at + len(g)))
    starts = [at for at, _ in goods]
    for i in (k for k, b in enumerate(stream) if b == 0x02 and k not in inside):
        if i + 4 > len(stream):
            break
        length = stream[i + 2] | (stream[i + 3] << 8)
        end = i + 4 + length + 2
        if (1 <= length <= 812 and end <= len(stream) and any(i < at < end for at in starts)
                and crc16(stream[i : end - 2]) == int.from_bytes(stream[end - 2 : end], "little")):
            return True
    return False


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.binary(max_size=40),
            _telegrams,
            st.integers(0, 1),
            st.integers(0, 999),
            st.integers(0, 7),
            _telegrams,
        ),
        min_size=1,
        max_size=5,
    ),
    st.integers(1, 64),
)
def test_garbage_flips_and_truncation_never_raise_and_intact_telegrams_survive(chunks, chunk_size):
    stream = b""
    intact = []
    for garbage, victim, how, pos, bit, good in chunks:
        damaged = _damaged(victim, how, pos, bit)
        # Where the damage leaves a frame with a good CRC that runs over the good telegram's STX, the
        # bytes are a valid telegram that swallowed it, and no reader can tell. Found by hypothesis:
        # a victim cut just before its last CRC byte, that byte 0x02, made whole by the next STX
        # (02 80 03 00 a5 02 00 16 | 02 80 ...); a victim cut to 10 bytes, those and the next
        # telegram's 8 a 12-byte frame whose CRC matches (1 in 65,536: 02 80 0c 00 3f 68 34 9e 66
        # 77 | 02 80 02 00 00 00 4b a0).
        stream += garbage + damaged
        intact.append((len(stream), good))
        stream += good
    assume(not _swallowed(stream, intact))
    intact = [g for _, g in intact]
    r = FrameReader()
    got = [t.encode() for i in range(0, len(stream), chunk_size) for t in r.feed(stream[i : i + chunk_size])]
    got += [t.encode() for t in r.flush()]
    it = iter(got)
    assert all(any(g == t for t in it) for g in intact), "an intact telegram was lost"


# ---- 0xB0 measured values ----


def test_count_word_bits_units_partial_index_and_count():
    data = (181 | 0x4000 | (1 << 13) | (2 << 11)).to_bytes(2, "little") + bytes(2 * 181)
    scan = decode_b0(Telegram(0xB0, data, 0x80, 0x10))
    assert (scan.count, scan.units, scan.partial, scan.partial_index) == (181, "mm", True, 2)
    assert math.degrees(scan.angles[0]) == pytest.approx(-90 + 0.5)


@pytest.mark.parametrize(
    ("count", "fov", "res"),
    [(181, 180, 1.0), (361, 180, 0.5), (101, 100, 1.0), (201, 100, 0.5), (401, 100, 0.25)],
)
def test_angles_run_counter_clockwise_from_minus_half_fov(count, fov, res):
    scan = decode_b0(FrameReader().feed(encode_b0(make_scan(np.ones(count), fov_deg=fov)))[0])
    assert (scan.fov_deg, scan.resolution_deg) == (fov, res)
    assert np.degrees(scan.angles[[0, -1]]) == pytest.approx([-fov / 2, fov / 2])
    assert np.all(np.diff(scan.angles) > 0)


def test_spec_aria_example_decodes_2000_plus_10i_millimetres():
    values = 2000 + 10 * np.arange(181)
    data = (181 | 0x4000).to_bytes(2, "little") + values.astype("<u2").tobytes()
    scan = decode_b0(Telegram(0xB0, data, 0x80, 0x10))
    assert scan.ranges.dtype == np.float32
    assert scan.ranges[0] == pytest.approx(2.0) and scan.ranges[180] == pytest.approx(3.8)


def test_mode0_flags_field_a_b_dazzle_sit_above_a_13_bit_range():
    v = 1234 | (1 << 13) | (1 << 15)  # field A + dazzle
    data = (1 | 0x4000).to_bytes(2, "little") + v.to_bytes(2, "little")
    scan = decode_b0(Telegram(0xB0, data, 0x80, 0x10), mode=0, fov_deg=0)
    assert scan.raw_ranges[0] == 1234 and scan.flags[0] == 0b101


@pytest.mark.parametrize(("mode", "bits"), [(1, 13), (3, 14), (4, 14), (5, 15), (6, 15), (0x0F, 16)])
def test_range_bits_and_flags_per_measuring_mode(mode, bits):
    v = 0xFFFF
    data = (1 | 0x4000).to_bytes(2, "little") + v.to_bytes(2, "little")
    scan = decode_b0(Telegram(0xB0, data, 0x80, 0x10), mode=mode, fov_deg=0)
    assert scan.raw_ranges[0] == (1 << bits) - 1 and scan.flags[0] == 0xFFFF >> bits


def test_8191_is_no_return_at_8191_m_in_mm_and_8191_m_in_cm():
    mm = make_scan([1.0, 9.0, np.nan], units="mm", mode=0)
    cm = make_scan([1.0, 90.0, np.inf], units="cm", mode=0)
    assert mm.max_range == pytest.approx(8.191) and cm.max_range == pytest.approx(81.91)
    assert mm.no_return.tolist() == [False, True, True] and cm.no_return.tolist() == [False, True, True]
    assert max_code(5) == 32767


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from([181, 361, 101, 201, 401]),
    st.sampled_from(["mm", "cm", "10cm"]),
    st.sampled_from(sorted(p.RANGE_BITS)),
    st.integers(0, 2**32 - 1),
    st.booleans(),
    st.integers(0, 255),
)
def test_decode_of_encode_is_identity(count, units, mode, seed, rt_index, status):
    rng = np.random.default_rng(seed)
    flags_bits = 16 - p.RANGE_BITS[mode]
    scan = make_scan(
        rng.uniform(0, 100, count),
        units=units,
        mode=mode,
        status=status,
        flags=rng.integers(0, 1 << flags_bits, count) if flags_bits else None,
        scan_index=int(rng.integers(0, 256)) if rt_index else None,
        t=1.5,
        fov_deg=180 if count in (181, 361) else 100,
    )
    back = decode_b0(FrameReader().feed(encode_b0(scan))[0], mode=mode, t=1.5)
    assert back == scan


def test_b0_with_wrong_length_is_a_value_error():
    with pytest.raises(ValueError, match="count word says 181"):
        decode_b0(Telegram(0xB0, (181 | 0x4000).to_bytes(2, "little") + bytes(10), 0x80, 0x10))


def test_scan_period_at_the_baud_and_the_mirror():
    assert b0_size(181) == 372
    assert transmit_time(372, 38400) == pytest.approx(0.0969, abs=1e-4)
    assert scan_period(181, 1.0, 38400) == pytest.approx(0.0969, abs=1e-4)  # ~10 Hz
    assert scan_period(361, 0.5, 38400) == pytest.approx(0.19, abs=1e-2)  # ~5 Hz
    assert scan_period(181, 1.0, 500000) == pytest.approx(1 / 75)  # the mirror: 75 Hz


def test_aria_resolution_zero_and_player_status_block_layout():
    assert p.VariantReply(True, 180, 100).encode() == bytes.fromhex("01 b4 00 64 00")
    assert p.status_variant(p.status_data("V02.10", 180, 50)) == (180, 50)
    assert len(p.status_data("V02.10", 180, 50)) + 1 >= 111
