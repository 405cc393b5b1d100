"""The host-side driver against the emulator over a real pty (spec p2os.md §1.3, §1.7, §1.9)."""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import replace

import pytest
import serial

from pioneer import Identity, LinkLost, OdometryError, Pioneer, PortUnavailable, Timeouts
from pioneer.commands import Command, command
from pioneer.emulator import PioneerEmulator
from pioneer.odometry import normalize_angle
from pioneer.params import P2DX
from tests.waiting import until

QUICK = replace(P2DX, trans_accel=5000, trans_decel=5000, rot_accel=2000, rot_decel=2000)
FAST = Timeouts(sync_reply=0.2, sync_attempts=5, close_settle=0.15, first_sip=0.5, keepalive=0.2,
                link_lost=0.4, reconnect_min=0.05, reconnect_max=0.2)
CYCLE = 0.05  # SIP cycle of the emulated robot in these tests (P2OS: 0.1 s)


def _emulator(pty_pair, **kw) -> PioneerEmulator:
    kw.setdefault("params", QUICK)
    kw.setdefault("sip_cycle", CYCLE)
    return PioneerEmulator(pty_pair.master, **kw).start()


def _pioneer(pty_pair, **kw) -> Pioneer:
    kw.setdefault("timeouts", FAST)
    return Pioneer(pty_pair.path, params=kw.pop("params", QUICK), **kw)


@pytest.fixture
def emu(pty_pair):
    e = _emulator(pty_pair, name="MockBot")
    yield e
    e.stop()


@pytest.fixture
def robot(pty_pair, emu):
    with _pioneer(pty_pair) as p:
        yield p


def _settle(robot: Pioneer, cycles: int = 4) -> None:
    for _ in range(cycles):
        robot.wait_odometry(1.0)


def _received(emu) -> list[tuple[str, int | None]]:
    return [(name, value) for _, name, value in emu.received]


# --- connecting -----------------------------------------------------------------------------------

def test_handshake_reads_identity_then_zero_velocity_precedes_enable(robot, emu):
    assert robot.identity == Identity("MockBot", "Pioneer", "p2dx")
    assert robot.link_state == "up"
    assert _received(emu)[:7] == [("SYNC0", None), ("SYNC1", None), ("SYNC2", None), ("OPEN", None),
                                  ("VEL", 0), ("RVEL", 0), ("ENABLE", 1)]
    assert robot.wait_odometry(1.0).sip.motors_enabled


def test_config_packet_is_read_when_requested(pty_pair, emu):
    with _pioneer(pty_pair, request_config=True) as p:
        assert p.config.subtype == "p2dx" and p.config.name == "MockBot"


def test_sip_during_handshake_leads_to_close_and_a_fresh_handshake(pty_pair, emu):
    leftover = serial.Serial(pty_pair.path, 9600, timeout=0.1)  # an earlier client left it open
    for n in range(3):
        leftover.write(command(n))
        time.sleep(0.03)
    leftover.write(command(Command.OPEN, 1))
    leftover.close()
    assert until(lambda: emu.counters["sips_sent"] > 2)
    with _pioneer(pty_pair) as p:
        assert p.counters["handshake_closes"] >= 1
        assert p.link_state == "up"
    assert emu.counters["sessions"] == 2
    assert "CLOSE" in emu.commands_seen()


def test_no_answer_names_what_to_check(pty_pair):
    with pytest.raises(LinkLost, match=r"no P2OS robot answered .* at 9600 baud.*dialout"):
        Pioneer(pty_pair.path, timeouts=Timeouts(sync_reply=0.05, sync_attempts=3))


def test_missing_port_is_reported_with_the_port_name():
    with pytest.raises(PortUnavailable, match=r"cannot open the Pioneer port: /dev/no-such-pioneer does not "
                       r"exist; check that the USB adapter is plugged in"):
        Pioneer("/dev/no-such-pioneer")


# --- odometry ---------------------------------------------------------------------------------------

def test_odometry_records_are_stamped_on_receipt_and_delivered_to_callbacks(robot, emu):
    got = []
    emu.battery = 11.3
    # A SIP is stamped when its first byte arrived (the read's time less its bytes' transfer time
    # at the baud), so one read just after registering may carry a stamp up to two SIPs earlier.
    before = time.monotonic() - 2 * 32 * 10.0 / robot.baudrate
    robot.on_odometry(got.append)
    _settle(robot, 3)
    assert len(got) >= 2 and all(before <= o.t <= time.monotonic() for o in got)
    assert [o.t for o in got] == sorted(o.t for o in got)
    assert got[-1].battery == pytest.approx(11.3)
    assert robot.history()[-1] == robot.odometry


def _drive_until(robot: Pioneer, v: float, w: float, done, timeout: float = 3.0) -> None:
    robot.set_velocity(v, w)
    start = robot.odometry
    end = time.monotonic() + timeout
    while time.monotonic() < end and not done(start, robot.wait_odometry(1.0)):
        pass
    robot.set_velocity(0.0, 0.0)


def test_square_odometry_matches_the_robot_and_the_true_pose_within_the_error_model(pty_pair):
    err = OdometryError(distance_scale=1.02, heading_scale=0.99)
    emu = _emulator(pty_pair, odometry_error=err)
    try:
        with _pioneer(pty_pair) as robot:
            _settle(robot, 2)
            for _ in range(4):
                _drive_until(robot, 2.0, 0.0, lambda a, b: math.hypot(b.x - a.x, b.y - a.y) >= 0.4)
                _drive_until(robot, 0.0, 6.0,
                             lambda a, b: normalize_angle(b.theta - a.theta) >= math.radians(85))
            _settle(robot, 5)
            odo, hist = robot.odometry, robot.history()
            # The driver reproduces the robot's own odometry (to the SIP's 0.84 mm, 0.088 deg units).
            ex, ey, eth = emu.odometry_pose
            assert (odo.x, odo.y) == pytest.approx((ex, ey), abs=0.002)
            assert normalize_angle(odo.theta - eth) == pytest.approx(0, abs=math.radians(0.2))
            # ... and the true motion differs from it exactly as the error model says.
            path = sum(math.hypot(b.x - a.x, b.y - a.y) for a, b in itertools.pairwise(hist))
            turned = sum(normalize_angle(b.theta - a.theta) for a, b in itertools.pairwise(hist))
            assert emu.body.distance * 1.02 == pytest.approx(path, rel=0.01)
            true_th_error = normalize_angle(emu.true_pose[2] - odo.theta)
            assert true_th_error == pytest.approx(turned * (1 / 0.99 - 1), abs=math.radians(0.3))
            assert turned > 2 * math.pi  # four corners of at least 85 deg, plus each one's braking
    finally:
        emu.stop()


@pytest.mark.parametrize(
    ("start", "v"),
    [((27.3, 0.0, 0.0), 1.0), ((0.2, 0.0, 0.0), -1.0), ((0.0, 27.3, math.pi / 2), 1.0)],
    ids=["x-forward-past-32767", "x-backward-past-0", "y-forward-past-32767"],
)
def test_odometry_is_continuous_across_the_15_bit_wraparound(pty_pair, start, v):
    emu = _emulator(pty_pair, start_pose=start)
    try:
        with _pioneer(pty_pair) as robot:
            _drive_until(robot, v, 0.0, lambda a, b: math.hypot(b.x, b.y) >= 0.5)
            _settle(robot, 4)
            hist = robot.history()
            raw = [o.sip.xpos if start[2] == 0 else o.sip.ypos for o in hist]
            assert max(raw) - min(raw) > 0x7000  # the SIP's position really wrapped
            steps = [math.hypot(b.x - a.x, b.y - a.y) for a, b in itertools.pairwise(hist)]
            assert max(steps) < 0.1  # no jump
            moved = math.hypot(emu.odometry_pose[0] - start[0], emu.odometry_pose[1] - start[1])
            assert math.hypot(robot.odometry.x, robot.odometry.y) == pytest.approx(moved, abs=0.002)
            assert math.copysign(1, robot.odometry.x) == v  # along the robot's initial heading
    finally:
        emu.stop()


def test_reset_odometry_restarts_both_at_the_origin(robot, emu):
    _drive_until(robot, 1.0, 1.0, lambda a, b: b.x > 0.2)
    _settle(robot, 3)
    robot.reset_odometry()
    _settle(robot, 4)
    assert robot.odometry.pose == pytest.approx((0, 0, 0), abs=0.002)
    assert emu.odometry_pose == pytest.approx((0, 0, 0), abs=0.002)


# --- commands ---------------------------------------------------------------------------------------

def test_velocity_is_clamped_to_the_robot_limits_and_sent_in_mm_and_degrees(robot, emu):
    assert robot.set_velocity(5.0, -20.0) == pytest.approx((2.2, -math.radians(500)))
    assert until(lambda: _received(emu)[-2:] == [("VEL", 2200), ("RVEL", -500)])


def test_wheel_velocities_go_out_as_vel2_and_turn_the_wheels(robot, emu):
    assert robot.set_wheel_velocities(-0.1, 0.1) == pytest.approx((-0.1, 0.1))
    assert until(lambda: robot.wait_odometry(1.0).left == pytest.approx(-0.1, abs=0.002))
    assert robot.odometry.right == pytest.approx(0.1, abs=0.002)
    assert emu.received[-1][1:] == ("VEL2", -(0x10000 - 0xFB05))  # ARIA style: 0x1B + |value|


def test_e_stop_halts_the_wheels_at_once(robot, emu):
    _drive_until(robot, 1.0, 0.0, lambda a, b: b.v > 0.9)
    robot.set_velocity(1.0, 0.0)
    robot.e_stop()
    assert until(lambda: "E_STOP" in emu.commands_seen())
    assert robot.wait_odometry(1.0) and until(lambda: robot.wait_odometry(1.0).v == 0, 0.2)


def test_sonar_off_clears_the_sonar_flags(robot):
    robot.sonar(False)
    assert until(lambda: robot.wait_odometry(1.0).sip.sonar_arrays == (False,) * 4)


# --- the link -----------------------------------------------------------------------------------------

def test_keepalive_pulses_keep_the_robot_watchdog_from_tripping(pty_pair):
    emu = _emulator(pty_pair, watchdog=0.3)
    try:
        with _pioneer(pty_pair) as robot:
            robot.set_velocity(0.3, 0.0)
            time.sleep(0.8)
            assert emu.counters["watchdog_trips"] == 0
            assert robot.counters["keepalives"] >= 2
            assert robot.odometry.v == pytest.approx(0.3, abs=0.01)
    finally:
        emu.stop()


def test_watchdog_stops_the_robot_when_the_host_goes_silent(pty_pair):
    emu = _emulator(pty_pair, watchdog=0.3)
    try:
        with _pioneer(pty_pair) as robot:
            robot.set_velocity(0.3, 0.0)
            robot.keepalive_enabled = False
            assert until(lambda: emu.counters["watchdog_trips"] == 1, 1.0)
            assert until(lambda: robot.wait_odometry(1.0).v == 0.0, 0.5)
            assert robot.link_state == "up"  # the robot still talks; only the host went quiet
    finally:
        emu.stop()


def test_lost_link_is_reported_and_reconnected_without_resuming_the_velocity(pty_pair):
    events = []
    first = _emulator(pty_pair)
    with _pioneer(pty_pair, on_link=lambda state, reason: events.append(state)) as robot:
        robot.set_velocity(0.3, 0.0)
        assert until(lambda: robot.odometry.v > 0.25)
        first.stop()  # the robot goes away...
        assert until(lambda: robot.link_state == "lost", 1.0)
        with pytest.raises(LinkLost, match="lost"):
            robot.set_velocity(0.1, 0.0)
        second = _emulator(pty_pair)  # ... and comes back, freshly powered on
        try:
            assert until(lambda: robot.link_state == "up", 3.0)
            _settle(robot, 4)
            assert events == ["up", "lost", "connecting", "up"]
            assert robot.counters["reconnects"] == 1 and robot.counters["links_lost"] == 1
            seen = _received(second)
            opened = seen.index(("OPEN", None))
            assert seen[opened + 1 : opened + 4] == [("VEL", 0), ("RVEL", 0), ("ENABLE", 1)]
            assert second.wheel_speeds == (0.0, 0.0) and robot.odometry.v == 0.0
        finally:
            second.stop()


def test_leaving_the_context_by_exception_stops_the_motors_and_closes(pty_pair, emu):
    with pytest.raises(RuntimeError, match="boom"), _pioneer(pty_pair) as robot:
        robot.set_velocity(0.5, 0.0)
        assert until(lambda: robot.wait_odometry(1.0).v > 0.4)
        raise RuntimeError("boom")
    assert until(lambda: emu.state == "waiting", 1.0)
    assert _received(emu)[-3:] == [("STOP", None), ("ENABLE", 0), ("CLOSE", None)]
    assert not emu.motors_enabled
    assert until(lambda: emu.wheel_speeds == (0.0, 0.0), 1.0)
    assert robot.link_state == "closed"


# --- what the SIP says is wrong -------------------------------------------------------------------------


def test_the_e_stop_and_a_low_battery_are_alerts_naming_the_remedy(robot, emu):
    assert robot.alerts == ()
    emu.estop_button = True
    emu.battery = 10.7
    assert until(lambda: len(robot.alerts) == 2, 1.0), robot.alerts
    estop, battery = robot.alerts
    assert estop.startswith("Pioneer e-stop pressed") and "release the red STOP button" in estop
    assert battery.startswith("Pioneer battery low: 10.7 V (below 11.0 V)") and "charge" in battery
    emu.estop_button = False  # released: the motors stay off until enabled again
    assert until(lambda: robot.alerts[:1] != (estop,), 1.0)
    assert robot.alerts[0].startswith("Pioneer motors disabled") and "MOTORS button" in robot.alerts[0]
    emu.battery = 12.5
    robot.close()


def test_sip_stamps_are_the_send_time_and_strictly_increasing(robot, emu):
    got = []
    robot.on_odometry(lambda o: got.append((time.monotonic(), o.t)))
    _settle(robot, 5)
    stamps = [t for _, t in got]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    # A SIP with n sonar readings is 30 + 3n bytes: at least 31 ms on the wire at 9600 baud.
    assert all(arrived - t >= 0.031 for arrived, t in got)


class PairedSipsEmulator(PioneerEmulator):
    """A robot behind a USB adapter that delivers its open-session SIPs two at a time."""

    def _write(self, data: bytes) -> None:
        if self.state != "open":
            return super()._write(data)
        held, self._held = getattr(self, "_held", b""), b""
        if held:
            return super()._write(held + data)
        self._held = data


def test_sips_arriving_together_keep_their_wire_spacing(pty_pair):
    emu = PairedSipsEmulator(pty_pair.master, params=QUICK, sip_cycle=CYCLE).start()
    try:
        with _pioneer(pty_pair) as robot:
            got = []
            robot.on_odometry(lambda o: got.append(o.t))
            _settle(robot, 8)
    finally:
        emu.stop()
    gaps = [b - a for a, b in itertools.pairwise(got)]
    # Each SIP (30 bytes and more) is at least 31 ms on the wire at 9600 baud: two SIPs read together
    # are stamped that far apart, not both at the read's time.
    assert min(gaps) >= 0.031 - 1e-6, gaps


def test_a_robot_that_stops_answering_is_lost_within_a_second(pty_pair):
    events = []
    first = _emulator(pty_pair)
    with _pioneer(pty_pair, on_link=lambda state, reason: events.append((time.monotonic(), state))):
        silent = time.monotonic()
        first.stop()
        assert until(lambda: any(s == "lost" for _, s in events), 1.0)
        lost = next(t for t, s in events if s == "lost")
        assert lost - silent < 1.0


def test_a_robot_at_another_baud_is_found_and_named(pty_pair):
    emu = _emulator(pty_pair, baud=38400)
    try:
        with pytest.raises(LinkLost, match=r"no P2OS robot answered on .* at 9600 baud, but one answered "
                                           r"SYNC0 at 38400 baud: set the baud to 38400"):
            Pioneer(pty_pair.path, params=QUICK, timeouts=Timeouts(sync_reply=0.05, sync_attempts=3))
        with _pioneer(pty_pair, baudrate=38400) as robot:
            assert robot.link_state == "up"
    finally:
        emu.stop()


def test_no_answer_at_any_baud_lists_the_bauds_tried(pty_pair):
    with pytest.raises(LinkLost, match=r"nor at any other P2OS baud \(19200, 38400, 57600, 115200\)"):
        Pioneer(pty_pair.path, timeouts=Timeouts(sync_reply=0.05, sync_attempts=3))
