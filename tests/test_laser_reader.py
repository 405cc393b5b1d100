"""LMS2xx reader against the emulator over real ptys: autobaud, start-up, scans, recovery, errors."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from laser.emulator import LMS2xxEmulator
from laser.errors import ConfigError, LinkLost
from laser.probe import emulated_laser, probe
from laser.reader import LMS2xx, Timeouts
from laser.sources import constant, fixed
from laser.timing import sweep_time, transmit_time
from laser.values import encode_b0, make_scan
from serialport.ptys import open_pty

FAST = Timeouts(probe=0.1, reply=0.5, settle=0.005, scan_margin=0.3, connect=0.0, recover=5.0, reset=2.0)


def _emulator(pair, **kw) -> LMS2xxEmulator:
    kw.setdefault("rate_limit", False)
    kw.setdefault("boot_time", 0.1)
    return LMS2xxEmulator(pair.master, **kw).start()


def _scans(lms: LMS2xx, n: int, timeout: float = 2.0) -> list:
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        scan = lms.read(timeout=deadline - time.monotonic())
        if scan is not None:
            out.append(scan)
    assert len(out) == n, f"got {len(out)} of {n} scans"
    return out


@pytest.mark.parametrize("start_baud", [9600, 19200, 38400, 500000])
def test_startup_finds_the_device_at_each_baud_switches_to_38400_and_close_returns_it_to_9600(
    pty_pair, start_baud
):
    emu = _emulator(pty_pair, baud=start_baud)
    try:
        with LMS2xx(pty_pair.path, 38400, timeouts=FAST) as lms:
            assert lms.detected_baud == start_baud
            assert (lms.baudrate, emu.baud, lms.link_state) == (38400, 38400, "up")
            assert lms.device_type == "LMS200;30106"
            assert _scans(lms, 2)[0].count == 181
        assert emu.baud == 9600 and not emu.streaming
        assert emu.counters["telegrams"][0x20] >= 5  # probe, baud, password, continuous, stop, 9600
    finally:
        emu.stop()


@pytest.mark.parametrize(
    ("fov", "res", "count"),
    [(180, 1.0, 181), (180, 0.5, 361), (100, 1.0, 101), (100, 0.5, 201), (100, 0.25, 401)],
)
def test_scans_have_the_variant_count_and_angles_from_minus_to_plus_half_fov(pty_pair, fov, res, count):
    with (
        _emulator(pty_pair, baud=38400),
        LMS2xx(pty_pair.path, resolution=res, fov=fov, timeouts=FAST) as lms,
    ):
        scan = _scans(lms, 1)[0]
        assert (scan.count, scan.fov_deg, scan.resolution_deg) == (count, fov, res)
        assert np.degrees(scan.angles[[0, count // 2, -1]]) == pytest.approx([-fov / 2, 0, fov / 2])


def test_mm_mode0_reports_8191_as_no_return_and_keeps_millimetres(pty_pair):
    source = fixed(np.r_[np.full(90, 1.234), np.full(91, 20.0)])  # 20 m is beyond the 8.191 m of mode 0
    with (
        _emulator(pty_pair, baud=38400, ranges=source),
        LMS2xx(pty_pair.path, units="mm", mode=0, timeouts=FAST) as lms,
    ):
        scan = _scans(lms, 1)[0]
        assert (scan.units, scan.mode, scan.max_range) == ("mm", 0, pytest.approx(8.191))
        assert scan.ranges.dtype == np.float32 and scan.ranges[0] == pytest.approx(1.234)
        assert scan.no_return.sum() == 91 and scan.ranges[-1] == pytest.approx(8.191)
        assert not scan.flags.any()


def test_cm_units_reach_81_m_and_the_device_config_block_is_edited_not_replaced(pty_pair):
    emu = _emulator(pty_pair, baud=38400, ranges=constant(20.0))
    try:
        with LMS2xx(pty_pair.path, units="cm", mode=0, timeouts=FAST) as lms:
            scan = _scans(lms, 1)[0]
            assert (scan.units, scan.max_range) == ("cm", pytest.approx(81.91))
            assert scan.ranges[90] == pytest.approx(20.0) and not scan.no_return.any()
            assert lms.config.raw[2] == 70  # the stop threshold the device reported is kept
        assert (emu.config.units, emu.config.mode) == ("cm", 0)
    finally:
        emu.stop()


def test_timestamp_is_the_first_ray_last_byte_minus_transmission_and_sweep(pty_pair):
    with _emulator(pty_pair, baud=38400), LMS2xx(pty_pair.path, timeouts=FAST) as lms:
        before = time.monotonic()
        scan = _scans(lms, 1)[0]
        after = time.monotonic()
        # A pty delivers at once, so the correction is the whole 372-byte telegram at 38400 baud
        # plus half a mirror turn (180 deg at 75 Hz: 6.7 ms) back to the first ray.
        back = transmit_time(372, 38400) + sweep_time(180, 1.0)
        assert sweep_time(180, 1.0) == pytest.approx(1 / 150)
        assert before - back - 0.05 <= scan.t <= after - back
        assert scan.t_first_ray == scan.t and scan.t_last_ray == pytest.approx(scan.t + 1 / 150)
        stamps = [s.t for s in _scans(lms, 10)]
        assert all(b > a for a, b in itertools.pairwise([scan.t, *stamps]))


@pytest.mark.parametrize("baud", [38400, 500000])
def test_the_emulator_samples_its_source_at_the_instant_the_reader_dates_the_scan(pty_pair, baud):
    asked = []

    def source(t, angles):
        asked.append(t)
        return np.full(len(angles), 2.0)

    with _emulator(pty_pair, baud=baud, ranges=source), LMS2xx(pty_pair.path, timeouts=FAST) as lms:
        scans = _scans(lms, 5)
    # The telegram is written at once; its sweep began its sweep and transmission times before.
    for scan in scans:
        nearest = min(asked, key=lambda t: abs(t - scan.t))
        assert abs(scan.t - nearest) < 0.005


def test_iterator_and_callback_both_deliver_scans(pty_pair):
    got = []
    with _emulator(pty_pair, baud=38400), LMS2xx(pty_pair.path, timeouts=FAST) as lms:
        lms.on_scan(got.append)
        for i, scan in enumerate(lms):
            assert scan.count == 181
            if i == 2:
                break
        assert got
        assert lms.counters["scans"] >= 3 and lms.counters["bad_crc"] == 0


def test_power_cycle_mid_stream_recovers_within_3_s_and_is_reported(pty_pair):
    events = []
    emu = _emulator(pty_pair, baud=9600, boot_time=0.3)
    try:
        with LMS2xx(pty_pair.path, 38400, timeouts=FAST) as lms:
            lms.on_link(events.append)
            _scans(lms, 2)
            emu.power_cycle()
            cut = time.monotonic()
            while lms.counters["recoveries"] == 0 and time.monotonic() - cut < 3.0:
                time.sleep(0.02)
            assert lms.counters["recoveries"] == 1, lms.counters
            assert time.monotonic() - cut < 3.0
            assert (lms.link_state, lms.counters["reboots"], lms.counters["link_lost"]) == ("up", 1, 1)
            assert [e.state for e in events][:3] == ["lost", "starting", "up"]
            assert lms.detected_baud == 9600 and emu.baud == 38400
            fresh = _scans(lms, 1)[0]
            assert fresh.t > cut
    finally:
        emu.stop()


def test_reset_waits_for_the_power_on_telegram(pty_pair):
    emu = _emulator(pty_pair, baud=19200, boot_time=0.2)
    try:
        with LMS2xx(pty_pair.path, 38400, reset=True, timeouts=FAST) as lms:
            assert lms.link_state == "up" and lms.baudrate == 38400
            _scans(lms, 1)
        assert emu.counters["telegrams"][0x10] == 1 and emu.counters["power_ons"] == 1
    finally:
        emu.stop()


def test_no_device_is_link_lost_saying_what_to_check(pty_pair):
    with pytest.raises(LinkLost) as err:
        LMS2xx(pty_pair.path, timeouts=Timeouts(probe=0.05, settle=0.0))
    msg = str(err.value)
    for words in ("expected reply A0", "9600", "500000", "powered", "permissions", "RS-422", pty_pair.path):
        assert words in msg
    assert isinstance(err.value, ConnectionError)


def test_impossible_variant_is_a_config_error_before_opening_anything():
    with pytest.raises(ConfigError, match=r"180 deg / 0\.25"):
        LMS2xx("/dev/does-not-exist", resolution=0.25, fov=180)


def test_a_device_that_goes_away_without_recovery_ends_the_iteration_with_link_lost(pty_pair):
    emu = _emulator(pty_pair, baud=38400)
    lms = LMS2xx(pty_pair.path, timeouts=FAST, recover=False)
    try:
        _scans(lms, 1)
        emu.stop()
        with pytest.raises(LinkLost):
            for _ in lms:
                pass
        assert lms.link_state == "down"
    finally:
        lms.close()
        emu.stop()


_B0 = encode_b0(make_scan(np.linspace(0.5, 7.5, 181), mode=5))
_noise = st.lists(
    st.one_of(
        st.binary(min_size=1, max_size=200),
        st.tuples(st.integers(0, 371), st.integers(0, 7)).map(lambda fb: _flip(*fb)),
        st.integers(1, 371).map(lambda n: _B0[:n]),
    ),
    min_size=1,
    max_size=4,
)


def _flip(pos: int, bit: int) -> bytes:
    b = bytearray(_B0)
    b[pos % len(b)] ^= 1 << bit
    return bytes(b)


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck))
@given(_noise)
def test_noise_between_telegrams_never_breaks_the_stream(noise):
    with open_pty() as pair, _emulator(pair, baud=38400) as emu, LMS2xx(pair.path, timeouts=FAST) as lms:
        errors = []
        lms.on_link(lambda e: errors.append(e) if e.state != "up" else None)
        _scans(lms, 1)
        for chunk in noise:
            emu.inject(chunk)
        seen = lms.counters["scans"]
        deadline = time.monotonic() + 2.0
        while lms.counters["scans"] < seen + 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert lms.counters["scans"] >= seen + 3
        assert lms.link_state == "up" and not errors


def test_a_port_that_cannot_be_opened_is_link_lost_naming_it():
    with pytest.raises(LinkLost, match="cannot open the LMS2xx port: /dev/no-such-lms does not exist"):
        LMS2xx("/dev/no-such-lms", timeouts=FAST)


def test_probe_reports_type_configuration_rate_and_ranges():
    with emulated_laser(constant(3.0), baud=9600, rate_limit=False, boot_time=0.05) as (pair, _emu):
        report = probe(pair.path, 38400, duration=0.3, timeouts=FAST)
    text = "\n".join(report.lines())
    assert report.device_type == "LMS200;30106" and report.detected_baud == 9600 and report.baudrate == 38400
    assert report.scans > 3 and report.count == 181
    assert report.ranges_m == pytest.approx((3.0, 3.0, 3.0))
    assert "units mm, measuring mode 5" in text and "Hz" in text
