"""Never run away: motion expires without fresh commands, a reconnected robot gets zero velocity
before ENABLE, and a thread dying of an exception stops the robot (the emulated Pioneer on a pty,
through the real driver)."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import pytest

from pioneer import Pioneer, Timeouts
from pioneer.emulator import PioneerEmulator
from pioneer.params import P2DX
from service.motion import MotionGate, stop_on_thread_crash
from tests.waiting import until

QUICK = replace(P2DX, trans_accel=5000, trans_decel=5000, rot_accel=2000, rot_decel=2000)
FAST = Timeouts(sync_reply=0.2, sync_attempts=5, close_settle=0.15, first_sip=0.5, keepalive=0.2,
                link_lost=0.4, reconnect_min=0.05, reconnect_max=0.2)


@pytest.fixture
def robot(pty_pair):
    emu = PioneerEmulator(pty_pair.master, QUICK, sip_cycle=0.05).start()
    with Pioneer(pty_pair.path, params=QUICK, timeouts=FAST) as dev:
        yield dev, emu
    emu.stop()


def test_without_a_new_command_for_half_a_second_the_robot_is_stopped(robot):
    dev, emu = robot
    gate = MotionGate(dev.set_velocity, dev.stop, max_age=0.5).start()
    try:
        gate.command(0.3, 0.0, "explore")
        assert until(lambda: emu.wheel_speeds[0] > 0.25, 1.0)
        for _ in range(8):  # a fresh source keeps it driving: 0.8 s of commands every 0.1 s
            time.sleep(0.1)
            # taken before the command: the gate's 0.5 s run from inside it (CI once saw 0.4997 s
            # from a clock read after it)
            silent = time.monotonic()
            gate.command(0.3, 0.0, "explore")
        # the source hangs; the driver's PULSEs keep P2OS's watchdog fed
        assert emu.wheel_speeds[0] > 0.25 and gate.expired == 0
        assert until(lambda: gate.expired == 1, 1.0)
        assert 0.5 <= gate.last_stop[0] - silent < 0.6
        assert gate.last_stop[1].startswith("no motion command from explore for 0.5")
        assert until(lambda: emu.wheel_speeds == (0.0, 0.0), 1.0)
        assert emu.counters["watchdog_trips"] == 0, "stopped by P2OS's watchdog, not by the gate"
    finally:
        gate.close()


def test_closing_the_gate_stops_the_robot(robot):
    dev, emu = robot
    gate = MotionGate(dev.set_velocity, dev.stop).start()
    gate.command(0.0, 0.5, "explore")
    assert until(lambda: emu.wheel_speeds[1] > 0.05, 1.0)
    gate.close()
    assert gate.last_stop[1] == "shutting down"
    assert until(lambda: emu.wheel_speeds == (0.0, 0.0), 1.0)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_thread_dying_of_an_exception_stops_the_robot(robot):
    dev, emu = robot
    reasons = []

    def stop(why: str) -> None:
        reasons.append(why)
        dev.stop()

    restore = stop_on_thread_crash(stop)
    try:
        dev.set_velocity(0.3, 0.0)
        assert until(lambda: emu.wheel_speeds[0] > 0.25, 1.0)

        def worker() -> None:
            raise RuntimeError("boom")

        t = threading.Thread(target=worker, name="worker")
        t.start()
        t.join()
        assert reasons == ["thread worker died: RuntimeError: boom"]
        assert until(lambda: emu.wheel_speeds == (0.0, 0.0), 1.0)
    finally:
        restore()


def test_after_any_reconnect_zero_velocity_precedes_enable(pty_pair):
    """The robot vanishes while driving and comes back: no old setpoint is resumed."""
    first = PioneerEmulator(pty_pair.master, QUICK, sip_cycle=0.05).start()
    with Pioneer(pty_pair.path, params=QUICK, timeouts=FAST) as dev:
        dev.set_velocity(0.3, 0.0)
        assert until(lambda: first.wheel_speeds[0] > 0.25, 1.0)
        first.stop()
        assert until(lambda: dev.link_state == "lost", 1.0)
        second = PioneerEmulator(pty_pair.master, QUICK, sip_cycle=0.05).start()
        try:
            assert until(lambda: dev.link_state == "up", 3.0)
            seen = [(name, value) for _, name, value in second.received]
            opened = seen.index(("OPEN", None))
            assert seen[opened + 1: opened + 4] == [("VEL", 0), ("RVEL", 0), ("ENABLE", 1)]
            time.sleep(0.2)
            assert second.wheel_speeds == (0.0, 0.0)
        finally:
            second.stop()
