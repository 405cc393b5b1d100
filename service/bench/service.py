"""The whole service, end to end: a scan telegram's last byte on the laser's pty to the matching
pose on a Zenoh subscriber in another process, and the service's CPU share of one core.

``asrmap run`` runs as a child process against the emulated LMS200 (500 kbaud, 75 scans/s, 181
beams of a room) and Pioneer 2DX (10 SIPs/s) on ptys; this process records when each 0xB0 telegram
was written and when each pose arrived on ``asrmap/<robot>/pose``. The pose rate is raised to 100 Hz
for the run so that every scan has a pose to match (the latency of one pose does not depend on how
many are published). The robot stands still: the mapper localises every scan in its ASR.

A pose carries its scan's time ``t`` (the driver's estimate of the telegram's first byte on the
line); the telegram it came from is the last one whose final byte was written before
``t + transmit time`` (+1 ms), unambiguous at 13 ms between scans.
"""

from __future__ import annotations

import bisect
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from serialport.ptys import PtyPair, open_pty

ROOT = Path(__file__).resolve().parents[2]

NAME = "service"
HELP = "asrmap run end to end: scan's last byte on a pty -> pose on Zenoh (goal p99 <= 20 ms), CPU share"

BAUD = 500000


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --- a robot on ptys and the service as a child process (also used by the tests) -------------------


class PluggedDevice:
    """An emulator on a pty reached through ``link`` (a symlink, as udev's /dev/sick is).

    :meth:`unplug` closes the pty as a pulled USB adapter vanishes; :meth:`plug` makes a new pty
    and points the link at it, as udev does when the adapter comes back.
    """

    def __init__(self, link: Path, make_emulator: Callable[[int], Any]):
        self.link = link
        self.make_emulator = make_emulator
        self.pair: PtyPair | None = None
        self.emulator: Any = None
        self.plug()

    def plug(self) -> None:
        self.pair = open_pty()
        self.emulator = self.make_emulator(self.pair.master)
        self.emulator.start()
        tmp = self.link.with_suffix(".new")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(self.pair.path)
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        self.link.unlink(missing_ok=True)
        if self.emulator is not None:
            self.emulator.stop()
        if self.pair is not None:
            self.pair.close()
        self.emulator = self.pair = None

    def close(self) -> None:
        self.unplug()


class Notifications:
    """A NOTIFY_SOCKET for a child service: collects its sd_notify datagrams."""

    def __init__(self, path: Path):
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.received: list[str] = []

    def wait_for(self, field: str, timeout: float) -> float:
        """Block until a datagram containing ``field`` arrives; returns its arrival time."""
        deadline = time.monotonic() + timeout
        if any(field in m for m in self.received):
            return time.monotonic()
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                msg = self.sock.recv(65536).decode()
            except TimeoutError:
                break
            self.received.append(msg)
            if field in msg:
                return time.monotonic()
        raise AssertionError(f"no {field} within {timeout} s; got {self.received}")

    def close(self) -> None:
        self.sock.close()


def write_config(path: Path, **sections: dict[str, Any]) -> Path:
    """A TOML file from ``section={key: value}`` (strings, numbers, booleans, lists of strings)."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(i) for i in v) + "]"
        return repr(v)

    lines = []
    for name, keys in sections.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {value(v)}" for k, v in keys.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


class ServiceProcess:
    """``asrmap run --config CONFIG`` as a child process with a notify socket and a log file."""

    def __init__(self, config: Path, workdir: Path, args: list[str] | None = None, watchdog_usec: int = 0):
        self.notify = Notifications(workdir / f"notify-{time.monotonic_ns()}")
        self.log_path = workdir / "service.log"
        env = {**os.environ, "NOTIFY_SOCKET": str(self.notify.path), "PYTHONUNBUFFERED": "1"}
        if watchdog_usec:
            env["WATCHDOG_USEC"] = str(watchdog_usec)
        cmd = args or [sys.executable, "-m", "service.cli", "run", "--config", str(config)]
        self._log = open(self.log_path, "a")  # noqa: SIM115 - lives as long as the process
        self.proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=self._log, stderr=subprocess.STDOUT)

    def log(self) -> str:
        return self.log_path.read_text()

    def terminate(self, timeout: float = 10.0) -> tuple[int, float]:
        """SIGTERM; returns (exit status, seconds until exit)."""
        t = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        rc = self.proc.wait(timeout)
        return rc, time.monotonic() - t

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def close(self) -> None:
        self.kill()
        self._log.close()
        self.notify.close()



# --- the benchmark ----------------------------------------------------------------------------------------


def _cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(args) -> dict:
    import zenoh

    from laser.emulator import LMS2xxEmulator
    from laser.sources import room
    from laser.timing import b0_size, sweep_time, transmit_time
    from pioneer.emulator import PioneerEmulator
    from service.bus import client_config

    seconds = 4.0 if getattr(args, "quick", False) else 20.0
    written: list[float] = []

    class TimedLMS(LMS2xxEmulator):
        """Records the time right after each 0xB0 telegram's last byte went into the pty."""

        def _send(self, data: bytes) -> None:
            super()._send(data)
            if len(data) > 4 and data[4] == 0xB0:
                written.append(time.monotonic())

    with tempfile.TemporaryDirectory(prefix="asrmap-bench-") as tmpd:
        tmp = Path(tmpd)
        laser = PluggedDevice(tmp / "sick", lambda fd: TimedLMS(fd, room(), rate_limit=False))
        robot = PluggedDevice(tmp / "pioneer", lambda fd: PioneerEmulator(fd))
        ep = f"tcp/127.0.0.1:{free_port()}"
        cfg = write_config(
            tmp / "asrmap.toml", robot={"name": "bench"},
            pioneer={"port": str(tmp / "pioneer")},
            laser={"port": str(tmp / "sick"), "baudrate": BAUD},
            zenoh={"listen": [ep]}, store={"state_dir": str(tmp)}, publish={"pose_rate": 100.0})
        svc = ServiceProcess(cfg, tmp)
        poses: list[tuple[float, float]] = []
        try:
            svc.notify.wait_for("READY=1", 30)
            session = zenoh.open(client_config([ep]))
            try:
                sub = session.declare_subscriber(
                    "asrmap/bench/pose",
                    lambda s: poses.append((time.monotonic(), json.loads(s.payload.to_bytes())["t"])))
                time.sleep(1.0)  # warm-up: connection, first ASR
                poses.clear()
                cpu0, wall0 = _cpu_seconds(svc.proc.pid), time.monotonic()
                first = len(written)
                threading.Event().wait(seconds)
                cpu1, wall1 = _cpu_seconds(svc.proc.pid), time.monotonic()
                sent = len(written) - first
                sub.undeclare()
            finally:
                session.close()
            rc, stop_s = svc.terminate()
        finally:
            svc.close()
            laser.close()
            robot.close()

    # A pose's t is its scan's first-ray stamp: the telegram's last byte less its transfer and the
    # mirror's sweep (laser.reader). Match it to the telegram written just after that.
    air = transmit_time(b0_size(181), BAUD) + sweep_time(180, 1.0)
    lat = []
    for received, t in poses:
        i = bisect.bisect_right(written, t + air + 1e-3) - 1
        if i >= 0:
            lat.append(received - written[i])
    lat_ms = np.array(lat) * 1e3
    cpu = (cpu1 - cpu0) / (wall1 - wall0)
    p50, p99 = (np.percentile(lat_ms, [50, 99]) if len(lat_ms) else (float("nan"), float("nan")))
    rate = sent / (wall1 - wall0)
    print(f"  {rate:.1f} scans/s sent at {BAUD} baud, {len(lat)} poses matched in {seconds:g} s")
    print(f"  scan last byte -> pose on a Zenoh subscriber: p50 {p50:.2f} ms, p99 {p99:.2f} ms "
          "(goal p99 <= 20 ms)")
    print(f"  service CPU: {100 * cpu:.1f}% of one core (goal <= 25%); "
          f"SIGTERM -> exit {rc} in {stop_s:.2f} s")
    sys.stdout.flush()
    return {"p50_ms": float(p50), "p99_ms": float(p99), "cpu_share": cpu, "poses": len(lat),
            "scans_per_s": rate, "exit": rc, "stop_s": stop_s}
