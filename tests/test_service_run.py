"""``asrmap run`` end to end: the service as a subprocess against the Pioneer and LMS200 emulators on
ptys (behind udev-like symlinks), watched over Zenoh from this process."""

from __future__ import annotations

import bisect
import itertools
import json
import math
import queue
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from laser.emulator import LMS2xxEmulator
from laser.sources import room
from mapper.se2 import interpolate, wrap
from pioneer.emulator import PioneerEmulator
from pioneer.physics import DiffDrive
from service.bench.service import ROOT, PluggedDevice, ServiceProcess, free_port, write_config
from service.bus import client_config


class Rig:
    """Emulated robot + ``asrmap run`` + a Zenoh session recording events and liveliness."""

    def __init__(self, tmp: Path, plug_laser: bool = True, make_robot=None, make_laser=None,
                 ports: tuple[str, str] | None = None, **extra: dict):
        """``ports``: (pioneer, laser) devices that exist elsewhere; else emulators on ptys here."""
        self.tmp = tmp
        self.robot = self.laser = None
        if ports is None:
            self.robot = PluggedDevice(tmp / "pioneer", make_robot or (lambda fd: PioneerEmulator(fd)))
            self.laser = PluggedDevice(tmp / "sick", make_laser or (
                lambda fd: LMS2xxEmulator(fd, room(), rate_limit=False)))
            if not plug_laser:
                self.laser.unplug()
            ports = (str(tmp / "pioneer"), str(tmp / "sick"))
        self.ep = f"tcp/127.0.0.1:{free_port()}"
        sections = {"robot": {"name": "rig"}, "pioneer": {"port": ports[0]},
                    "laser": {"port": ports[1]}, "zenoh": {"listen": [self.ep]},
                    "store": {"state_dir": str(tmp)},
                    "watchdog": {"reconnect_interval": 0.2, "scan_timeout": 0.5}}
        for k, v in extra.items():
            sections[k] = {**sections.get(k, {}), **v}
        self.config = write_config(tmp / "asrmap.toml", **sections)
        self.events: queue.Queue = queue.Queue()
        self.alive: queue.Queue = queue.Queue()
        self.asrs: queue.Queue = queue.Queue()
        self.status: queue.Queue = queue.Queue()
        self.session = zenoh.open(client_config([self.ep]))
        self._decls = [
            self.session.declare_subscriber("asrmap/rig/event", self._json(self.events)),
            self.session.declare_subscriber("asrmap/rig/asr/*", self._json(self.asrs)),
            self.session.declare_subscriber("asrmap/rig/status", self._json(self.status)),
            self.session.liveliness().declare_subscriber(
                "asrmap/rig/alive", lambda s: self.alive.put(s.kind), history=True),
        ]
        self.service = ServiceProcess(self.config, tmp)

    @staticmethod
    def _json(q: queue.Queue):
        return lambda s: q.put(json.loads(s.payload.to_bytes()))

    def event(self, kind: str, timeout: float = 10.0, **match) -> dict:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                e = self.events.get(timeout=left)
            except queue.Empty:
                break
            if e["event"] == kind and all(e.get(k) == v for k, v in match.items()):
                return e
        raise AssertionError(f"no {kind} event {match} within {timeout} s\n{self.service.log()[-3000:]}")

    def ready(self) -> None:
        """READY=1 from the service, and this session connected to it (its token seen)."""
        self.service.notify.wait_for("READY=1", 20)
        assert self.alive.get(timeout=10) == zenoh.SampleKind.PUT

    def get(self, selector: str):
        for r in self.session.get(selector, timeout=5.0):
            if r.ok:
                return json.loads(r.ok.payload.to_bytes()), None
            return None, json.loads(r.err.payload.to_bytes())
        raise AssertionError(f"no reply to {selector}")

    def close(self) -> None:
        self.service.close()
        for d in self._decls:
            d.undeclare()
        self.session.close()
        for dev in (self.laser, self.robot):
            if dev is not None:
                dev.close()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


def test_the_service_maps_publishes_and_stops_the_robot_on_sigterm(tmp_path):
    """Started with the laser unplugged: Zenoh is up first (token, fault), the laser arrives
    (recovered, READY, the first ASR), and SIGTERM leaves the motors stopped and the laser quiet."""
    rig = Rig(tmp_path, plug_laser=False)
    try:
        assert rig.alive.get(timeout=15) == zenoh.SampleKind.PUT
        # The first fault may precede this session's connection; the status repeats it.
        blind = rig.status.get(timeout=5)
        while blind["laser"]["link"] == "connecting":
            blind = rig.status.get(timeout=5)
        assert blind["laser"]["link"] == "fault" and blind["laser"]["reason"].startswith("cannot open")
        rig.laser.plug()
        rig.event("recovered", device="laser")
        rig.service.notify.wait_for("READY=1", 15)
        created = rig.event("asr_created", asr=1)
        assert created["schema"] == "asrmap/event/1"
        asr = rig.asrs.get(timeout=5)
        assert asr["schema"] == "asrmap/asr/1" and asr["id"] == 1 and len(asr["boundary"]) >= 3

        status = rig.status.get(timeout=5)
        # the link is ok once the laser answers; a status may come before its first scan is counted
        while status["laser"]["link"] != "ok" or status["rates"]["scans"] == 0:
            status = rig.status.get(timeout=5)
        assert status["pioneer"]["link"] == "ok" and status["battery"] == pytest.approx(12.5, abs=0.1)
        assert status["rates"]["scans"] > 0 and status["dropped_scans"] >= 0

        doc, _ = rig.get("asrmap/rig/map")
        from mapper.document import from_document

        assert doc["schema"] == "asrmap/map/1" and doc["robot"] == "rig"
        assert [a.id for a in from_document(doc).asrs][:1] == [1]

        robot, laser = rig.robot.emulator, rig.laser.emulator
        assert robot.state == "open" and laser.streaming
        rc, seconds = rig.service.terminate()
        assert rc == 0 and seconds < 2.0, rig.service.log()[-2000:]
        assert rig.alive.get(timeout=5) == zenoh.SampleKind.DELETE
        assert robot.wheel_speeds == (0.0, 0.0) and not robot.motors_enabled and robot.state == "waiting"
        assert {"STOP", "CLOSE"} <= set(robot.commands_seen())
        assert not laser.streaming, "the laser's continuous output was not stopped"
        assert "Traceback" not in rig.service.log()
    finally:
        rig.close()


def test_a_laser_replugged_under_the_same_name_is_recovered_without_a_restart(rig):
    rig.ready()
    rig.event("asr_created", asr=1)
    stops = rig.robot.emulator.commands_seen().count("STOP")
    rig.laser.unplug()
    fault = rig.event("fault", device="laser")
    assert fault["reason"].startswith("no data for")
    time.sleep(0.3)
    assert rig.robot.emulator.commands_seen().count("STOP") > stops, "the robot was not stopped while blind"
    rig.laser.plug()
    rig.event("recovered", device="laser")
    deadline = time.monotonic() + 5
    while (st := rig.status.get(timeout=5))["laser"]["rate"] < 5 and time.monotonic() < deadline:
        pass
    assert st["laser"]["link"] == "ok" and st["laser"]["faults"] == 1 and st["laser"]["recoveries"] == 1
    assert rig.service.proc.poll() is None


def test_a_refused_command_has_no_effect_and_an_allowed_stop_stops_the_robot(tmp_path):
    rig = Rig(tmp_path, zenoh={"allow_commands": ["stop"]})
    try:
        rig.ready()
        time.sleep(0.3)
        seen = list(rig.robot.emulator.commands_seen())
        ok, err = rig.get("asrmap/rig/cmd/explore")
        assert ok is None and err["error"].startswith("command explore is disabled: add")
        time.sleep(0.3)
        after = rig.robot.emulator.commands_seen()[len(seen):]
        assert set(after) <= {"PULSE"}, after

        ok, err = rig.get("asrmap/rig/cmd/stop")
        assert err is None and ok == {"schema": "asrmap/command/1", "command": "stop", "stopped": True}
        time.sleep(0.3)
        assert rig.robot.emulator.commands_seen()[len(seen):].count("STOP") == 1
    finally:
        rig.close()


@pytest.mark.parametrize(("text", "line"), [
    ("[laser]\nbaudrate = 12345\n",
     "laser.baudrate: expected one of 9600, 19200, 38400, 500000; found 12345"),
    ('[pioneer]\nprot = "/dev/ttyUSB0"\n', "pioneer.prot: expected one of the keys port, baudrate, model; "
                                            "found an unknown key"),
    ("[zenoh\n", "not valid TOML"),
    (f'[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n[store]\nstate_dir = "/dev/null/asrmap"\n',
     "cannot open the map store /dev/null/asrmap/map.sqlite: Not a directory; check [store] state_dir"),
])
def test_a_bad_config_file_is_one_clear_line(tmp_path, text, line):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    r = subprocess.run([sys.executable, "-m", "service.cli", "run", "--config", str(cfg)], cwd=ROOT,
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("asrmap run: ") and line in lines[0], r.stderr


def test_a_busy_zenoh_port_is_one_clear_line(rig, tmp_path):
    rig.ready()
    r = subprocess.run([sys.executable, "-m", "service.cli", "run", "--config", str(rig.config)], cwd=ROOT,
                       capture_output=True, text=True, timeout=30)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("asrmap run: cannot open the zenoh session (listen ") and "in use" in lines[0]
    assert ".rs:" not in lines[0] and "[zenoh] listen" in lines[0]


class ScriptedDrive(DiffDrive):
    """A body that follows a scripted trajectory (true = odometry pose) once ``go`` is set, whatever
    the service commands: a robot pushed around a corridor loop."""

    def __init__(self, truth, speed: float, turn_rate: float):
        super().__init__(start_pose=truth[0])
        self.truth = truth
        self.times = [0.0]
        for a, b in itertools.pairwise(truth):
            dist = math.hypot(b[0] - a[0], b[1] - a[1])
            self.times.append(self.times[-1] + max(dist / speed, abs(wrap(b[2] - a[2])) / turn_rate))
        self.clock = 0.0
        self.go = False

    def step(self, dt: float) -> None:
        if not self.go:
            return
        self.clock = min(self.clock + dt, self.times[-1])
        i = max(1, bisect.bisect_left(self.times, self.clock))
        f = (self.clock - self.times[i - 1]) / (self.times[i] - self.times[i - 1])
        self.true_pose = self.odometry_pose = interpolate(self.truth[i - 1], self.truth[i], f)


def test_driving_a_loop_publishes_asr_exit_and_cycle_events(tmp_path):
    from tests.raycast import cast
    from tests.synthetic_runs import LOOP_WAYPOINTS, corridor_loop, path

    body = ScriptedDrive(path(LOOP_WAYPOINTS, laps=1.4, step=0.05), speed=5.0, turn_rate=math.pi)
    walls = corridor_loop()

    def ranges(t, angles):
        return cast(walls, body.true_pose, n=len(angles), max_range=30.0, no_return=32.767).ranges

    rig = Rig(tmp_path, mapper={"laser_x": 0.0, "laser_y": 0.0},
              make_robot=lambda fd: PioneerEmulator(fd, body=body),
              make_laser=lambda fd: LMS2xxEmulator(fd, ranges, rate_limit=False))
    try:
        rig.ready()
        rig.event("asr_created", asr=1)
        body.go = True
        seen = set()
        deadline = time.monotonic() + body.times[-1] + 10
        while not {"exit_crossed", "cycle"} <= seen and time.monotonic() < deadline:
            try:
                e = rig.events.get(timeout=1)
            except queue.Empty:
                continue
            seen.add("cycle" if e["event"] in ("cycle_detected", "cycle_rejected") else e["event"])
            if e["event"].startswith("cycle_"):
                assert {"asr", "matches", "iou", "reason", "accepted"} <= set(e)
        assert {"exit_crossed", "cycle"} <= seen, seen
        doc, _ = rig.get("asrmap/rig/map")
        assert len(doc["asrs"]) >= 3 and doc["links"] and doc["cycles"]
    finally:
        rig.close()


def _explore_until_the_robot_moves(rig: Rig, world) -> None:
    """``cmd/explore``, then wait until the simulated robot has moved (0.3 m or 0.5 rad)."""
    rig.ready()
    start = world.robot.drive.true_pose
    ok, err = rig.get("asrmap/rig/cmd/explore")
    assert err is None and ok["exploring"] is True
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        x, y, th = world.robot.drive.true_pose
        if math.hypot(x - start[0], y - start[1]) > 0.3 or abs(wrap(th - start[2])) > 0.5:
            return
        time.sleep(0.2)
    raise AssertionError(f"the robot did not move\n{rig.service.log()[-2000:]}")


def test_a_service_killed_while_exploring_leaves_the_wheels_stopped(tmp_path):
    """SIGKILL gives the service no chance to send a stop: the robot's own P2OS watchdog (2 s with
    no command) must stop the wheels, and nothing may restart them."""
    from service.sim.simulator import WorldDevices
    from service.sim.world import load_world

    with WorldDevices(load_world("lab")) as world:
        rig = Rig(tmp_path, ports=(world.pioneer_path, world.laser_path),
                  zenoh={"allow_commands": ["explore"]})
        try:
            _explore_until_the_robot_moves(rig, world)
            drive = world.robot.drive
            rig.service.kill()
            deadline = time.monotonic() + 4.0  # the 2 s watchdog, then P2OS's deceleration
            while time.monotonic() < deadline and (drive.left_speed or drive.right_speed):
                time.sleep(0.05)
            assert drive.left_speed == 0.0 and drive.right_speed == 0.0
            pose = drive.true_pose
            time.sleep(1.0)
            assert drive.true_pose == pose and drive.left_speed == drive.right_speed == 0.0
        finally:
            rig.close()


def test_cmd_explore_drives_the_robot_and_cmd_stop_stops_it(tmp_path):
    """In the simulated lab (both emulators ray cast and move in one world), with both commands
    allowed: explore makes the robot move on its own; stop ends exploring and the wheels stop."""
    from service.sim.simulator import WorldDevices
    from service.sim.world import load_world

    with WorldDevices(load_world("lab")) as world:
        rig = Rig(tmp_path, ports=(world.pioneer_path, world.laser_path),
                  zenoh={"allow_commands": ["stop", "explore"]})
        try:
            _explore_until_the_robot_moves(rig, world)
            ok, err = rig.get("asrmap/rig/cmd/stop")
            assert err is None and ok["stopped"] is True
            time.sleep(1.5)  # P2OS decelerates
            assert world.robot.drive.left_speed == 0.0 and world.robot.drive.right_speed == 0.0
            status = rig.status.get(timeout=3)
            while status["explore"]["status"] in ("idle", "starting") or status["explore"]["active"]:
                status = rig.status.get(timeout=3)
            assert status["explore"] == {"active": False, "status": "stopped: cmd/stop"}
        finally:
            rig.close()



def test_a_laser_talking_garbage_and_a_vanished_pioneer_are_recovered(rig):
    """A power-cycled LMS comes back at 9600 baud: the host at 38400 reads garbage, then nothing.
    A Pioneer whose port disappears and comes back is reopened with its odometry continuing."""
    rig.ready()
    rig.laser.emulator.power_cycle(0.3)
    assert rig.event("fault", device="laser")["reason"].startswith("no data for")
    rig.event("recovered", device="laser")
    rig.robot.unplug()
    rig.event("fault", device="pioneer")
    rig.robot.plug()
    rig.event("recovered", device="pioneer")
    st = rig.status.get(timeout=5)
    while st["pioneer"]["recoveries"] < 1 or st["pioneer"]["link"] != "ok":
        st = rig.status.get(timeout=5)
    assert st["laser"] | {"rate": 0, "counters": {}, "driver": None} == {
        "link": "ok", "reason": None, "faults": 1, "recoveries": 1, "rate": 0, "counters": {}, "driver": None}
    assert rig.service.proc.poll() is None and "Traceback" not in rig.service.log()
