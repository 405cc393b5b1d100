"""Hardware bring-up behind ``asrmap probe pioneer`` and ``asrmap emulate pioneer``.

:func:`probe` connects without enabling the motors (zero velocity is still sent), reads the CONFIG
packet if the robot answers it, records every SIP for a few seconds, and closes (STOP, ENABLE 0,
CLOSE). Failures raise the driver's typed errors, whose messages say what to check.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from pioneer.driver import Identity, Pioneer, Timeouts
from pioneer.emulator import PioneerEmulator
from pioneer.odometry import PioneerOdometry
from pioneer.params import P2DX, RobotParams
from serialport.ptys import open_pty


@dataclass(frozen=True)
class ProbeReport:
    """What one connection and ``duration`` seconds of SIPs showed (odometry frame, SI units)."""

    port: str
    baudrate: int
    identity: Identity
    config: object | None
    duration: float
    records: tuple[PioneerOdometry, ...]
    params: RobotParams = P2DX
    counters: dict = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        return len(self.records) / self.duration if self.duration > 0 else 0.0

    def sip_line(self, o: PioneerOdometry, t0: float) -> str:
        s = o.sip
        sonar = " ".join(f"{n}:{mm / 1000:.2f}" for n, mm in s.sonar_mm(self.params.range_conv).items())
        stall = ("L" if s.left_stall else "-") + ("R" if s.right_stall else "-")
        estop = "YES" if s.e_stop else "no"
        return (
            f"  {o.t - t0:6.3f}s x {o.x:+.3f} y {o.y:+.3f} m th {math.degrees(o.theta):+7.2f} deg  "
            f"v {o.v:+.3f} m/s w {math.degrees(o.w):+6.1f} deg/s  batt {s.battery_volts:.1f} V  "
            f"motors {'on' if s.motors_enabled else 'off'} stall {stall} estop {estop}  "
            f"raw x {s.xpos} y {s.ypos} th {s.thpos}" + (f"  sonar m {sonar}" if sonar else "")
        )

    def lines(self) -> list[str]:
        """The report as ``asrmap probe pioneer`` prints it."""
        i = self.identity
        out = [f"robot    {i.name!r}, class {i.robot_class}, subclass {i.subclass} on {self.port} "
               f"at {self.baudrate} baud"]
        c = self.config
        if c is not None:
            out.append(f"config   firmware {c.firmware_version!r}, serial {c.serial_number!r}, "
                       f"SIP cycle {c.sip_cycle} ms, watchdog {c.watchdog} ms, "
                       f"max {c.trans_vel_max} mm/s {c.rot_vel_max} deg/s")
        else:
            out.append("config   (no reply to CONFIG; older P2OS firmware does not send one)")
        out.append(f"SIPs     {len(self.records)} in {self.duration:.1f} s = {self.rate_hz:.1f} Hz")
        t0 = self.records[0].t if self.records else 0.0
        out += [self.sip_line(o, t0) for o in self.records]
        out.append("counters " + ", ".join(f"{k} {v}" for k, v in self.counters.items()))
        return out


def probe(
    port: str,
    baudrate: int = 9600,
    seconds: float = 2.0,
    params: RobotParams = P2DX,
    timeouts: Timeouts | None = None,
) -> ProbeReport:
    """Connect to the robot on ``port`` (look only: motors not enabled), record ``seconds`` of SIPs."""
    records: list[PioneerOdometry] = []
    with Pioneer(port, baudrate, params, timeouts=timeouts, request_config=True, reconnect=False,
                 enable_motors=False) as robot:
        robot.on_odometry(records.append)
        start = time.monotonic()
        time.sleep(seconds)
        duration = time.monotonic() - start
        assert robot.identity is not None
        return ProbeReport(port, baudrate, robot.identity, robot.config, duration, tuple(records), params,
                           robot.counters)


@contextmanager
def emulated(params: RobotParams = P2DX, **kwargs) -> Iterator[tuple[str, PioneerEmulator]]:
    """``(path, emulator)``: an emulated Pioneer on a new pty for as long as the block runs; ``path``
    is the device a driver opens (``kwargs`` go to :class:`PioneerEmulator`)."""
    with open_pty() as pair, PioneerEmulator(pair.master, params, **kwargs) as emu:
        yield pair.path, emu
