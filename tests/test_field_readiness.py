"""Field readiness of ``asrmap run`` (a child process) against the emulated Pioneer and LMS200 on
ptys behind udev-like symlinks: it starts before the devices exist and says what it waits for,
gives up after its start-up budget, reports the robot's state and its own timing in ``status``,
and heals a robot that stops answering and comes back."""

from __future__ import annotations

import json
import queue
import time
from pathlib import Path

import pytest
import zenoh

from laser.emulator import LMS2xxEmulator
from laser.sources import room
from pioneer.emulator import PioneerEmulator
from service.bench.service import PluggedDevice, ServiceProcess, free_port, write_config
from service.bus import client_config


def _config(tmp: Path, ep: str, **watchdog) -> Path:
    return write_config(tmp / "asrmap.toml", robot={"name": "field"},
                        pioneer={"port": str(tmp / "pioneer")}, laser={"port": str(tmp / "sick")},
                        zenoh={"listen": [ep]}, store={"state_dir": str(tmp)},
                        watchdog={"reconnect_interval": 0.2, "scan_timeout": 0.5, **watchdog})


def _statuses(service: ServiceProcess) -> list[str]:
    """The STATUS= lines received so far (every queued datagram read first)."""
    sock = service.notify.sock
    sock.setblocking(False)
    try:
        while True:
            service.notify.received.append(sock.recv(65536).decode())
    except BlockingIOError:
        pass
    finally:
        sock.setblocking(True)
    return [m for m in service.notify.received if m.startswith("STATUS=")]


def _wait_status(service: ServiceProcess, text: str, timeout: float) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for m in _statuses(service):
            if text in m:
                return m
        sock = service.notify.sock
        sock.settimeout(0.5)
        try:
            service.notify.received.append(sock.recv(65536).decode())
        except TimeoutError:
            pass
    raise AssertionError(f"no STATUS with {text!r}: {_statuses(service)}\n{service.log()[-2000:]}")


def _robot(fd: int) -> PioneerEmulator:
    return PioneerEmulator(fd)


def _laser(fd: int) -> LMS2xxEmulator:
    return LMS2xxEmulator(fd, room(), rate_limit=False)


def test_started_before_the_devices_it_says_what_it_waits_for_then_becomes_ready(tmp_path):
    service = ServiceProcess(_config(tmp_path, f"tcp/127.0.0.1:{free_port()}"), tmp_path)
    robot = laser = None
    try:
        line = _wait_status(service, "cannot open the LMS2xx port", 15)
        pioneer = tmp_path / "pioneer"
        assert line.startswith(f"STATUS=waiting for the pioneer on {pioneer} (cannot open: cannot "
                               f"open the Pioneer port: {pioneer} does not exist;")
        assert f"the laser on {tmp_path / 'sick'} (cannot open: cannot open the LMS2xx port" in line
        assert " s of 90 s)" in line
        assert not any("READY=1" in m for m in service.notify.received)
        robot = PluggedDevice(tmp_path / "pioneer", _robot)  # USB enumerates late
        _wait_status(service, "waiting for the laser on", 10)
        laser = PluggedDevice(tmp_path / "sick", _laser)
        service.notify.wait_for("READY=1", 15)
        assert service.proc.poll() is None
    finally:
        service.close()
        for dev in (robot, laser):
            if dev is not None:
                dev.close()


def test_devices_missing_beyond_the_start_up_budget_exit_1_naming_them(tmp_path):
    service = ServiceProcess(_config(tmp_path, f"tcp/127.0.0.1:{free_port()}", startup_timeout=1.5), tmp_path)
    try:
        rc = service.proc.wait(20)
        assert rc == 1
        assert "gave up after 2 s (watchdog.startup_timeout) waiting for the pioneer on" in service.log()
        assert any(m.startswith("STATUS=gave up waiting for the pioneer") for m in _statuses(service))
    finally:
        service.close()


@pytest.fixture
def field(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    robot = PluggedDevice(tmp_path / "pioneer", _robot)
    laser = PluggedDevice(tmp_path / "sick", _laser)
    status: queue.Queue = queue.Queue()
    events: queue.Queue = queue.Queue()
    session = zenoh.open(client_config([ep]))
    subs = [session.declare_subscriber(f"asrmap/field/{key}",
                                       lambda s, q=q: q.put(json.loads(s.payload.to_bytes())))
            for key, q in (("status", status), ("event", events))]
    service = ServiceProcess(_config(tmp_path, ep), tmp_path)
    try:
        service.notify.wait_for("READY=1", 20)
        yield service, robot, laser, status, events
    finally:
        service.close()
        for s in subs:
            s.undeclare()
        session.close()
        laser.close()
        robot.close()


def _status_until(status: queue.Queue, cond, timeout: float = 10.0) -> dict:
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            last = status.get(timeout=max(0.01, deadline - time.monotonic()))
        except queue.Empty:
            break
        if cond(last):
            return last
    raise AssertionError(f"no status matching within {timeout} s; last: {last}")


def _event(events: queue.Queue, kind: str, device: str, timeout: float = 10.0) -> tuple[float, dict]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        e = events.get(timeout=max(0.01, deadline - time.monotonic()))
        if e["event"] == kind and e.get("device") == device:
            return time.monotonic(), e
    raise AssertionError(f"no {kind} of {device}")


def test_status_reports_timing_motors_battery_and_the_reason_for_the_last_stop(field):
    _, robot, laser, status, events = field
    st = _status_until(status, lambda s: s["timing"].get("latency") is not None and s["rates"]["sips"] > 5)
    t = st["timing"]
    assert 0 < t["latency"] < 0.5 and t["realtime_factor"] > 1 and 0 <= t["cpu_share"] < 2
    # Both stamps are first-byte times on one clock: a scan is at most a SIP cycle (plus jitter)
    # newer than the newest SIP.
    assert -0.05 < t["skew"] < 0.2, t
    assert st["motors"] == {"enabled": True, "e_stop": False, "alerts": []}
    assert st["battery"] == pytest.approx(12.5) and st["waiting_for"] is None
    robot.emulator.estop_button = True
    robot.emulator.battery = 10.6
    st = _status_until(status, lambda s: s["motors"]["e_stop"])
    assert st["motors"]["enabled"] is False
    alerts = [a.split(":")[0] for a in st["motors"]["alerts"]]
    assert alerts == ["Pioneer e-stop pressed", "Pioneer battery low"]
    laser.unplug()
    _event(events, "fault", "laser")
    st = _status_until(status, lambda s: s["last_stop"] is not None)
    assert st["last_stop"]["reason"] == "the laser is blind"
    assert st["laser"]["link"] == "fault"


def test_a_robot_that_stops_answering_is_noticed_within_a_second_and_recovered(field):
    service, robot, _, status, events = field
    robot.emulator.stop()  # the P2OS controller hangs; the USB adapter (the pty) stays
    silent = time.monotonic()
    noticed, fault = _event(events, "fault", "pioneer")
    assert noticed - silent < 1.0, fault
    robot.emulator = _robot(robot.pair.master).start()  # reset: back in its waiting state
    _event(events, "recovered", "pioneer")
    st = _status_until(status, lambda s: s["pioneer"]["link"] == "ok" and s["rates"]["sips"] > 5)
    assert st["pioneer"]["faults"] == 1 and st["pioneer"]["recoveries"] == 1
    seen = robot.emulator.commands_seen()
    opened = seen.index("OPEN")
    assert seen[opened + 1: opened + 4] == ["VEL", "RVEL", "ENABLE"]
    assert service.proc.poll() is None and "Traceback" not in service.log()
