"""A Pioneer 2DX running P2OS, on the master side of a pty (robot side; spec p2os.md §1).

Session states follow the P2OS manual and MobileSim: ``waiting`` -> SYNC0 echoed -> ``sync0`` ->
SYNC1 echoed -> ``sync1`` -> SYNC2 answered with name/class/subclass -> ``sync2`` -> command 1
(OPEN, with or without an argument) -> ``open``: a SIP every cycle until CLOSE (back to
``waiting``). Whatever any client sends is tolerated: ASCII before the sync (ARIA's ``"WMS2\\r"``),
0x1B negative integers, both VEL2 encodings, ``SETO 3B`` without its integer; unknown commands are
ignored and counted.

The motion itself is a :class:`pioneer.physics.DiffDrive` (or any :class:`pioneer.physics.Body`),
stepped once per SIP cycle. The 2 s watchdog zeroes the setpoints when the client falls silent
while the session is open; motion resumes only on a new velocity command (a conservative reading of
"resume again on receipt of a client packet"). The codec is the driver's (:mod:`pioneer.packet`,
:mod:`pioneer.commands`, :mod:`pioneer.sip`).

A pty carries bytes at once whatever its baud, but a real SIP reaches the host one transfer time
(ten bits a byte at the line's baud, as the host set it on the pty) after the robot sampled it, and
the driver dates it back by that much: each SIP is written that long after its sampling tick.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import select
import termios
import threading
import time
from collections import Counter, deque
from collections.abc import Callable

from pioneer.commands import (
    Command,
    CommandPacket,
    command,
    parse_command,
    sync2_reply,
    vel2_wheels,
)
from pioneer.packet import Packet, PacketReader, frame
from pioneer.params import P2DX, RobotParams
from pioneer.physics import Body, DiffDrive, MotionHook, OdometryError, Pose
from pioneer.sip import SIP, EncoderCounts, RobotConfig, encode_config, encode_encoder, encode_sip
from serialport.device import DeviceThread

log = logging.getLogger(__name__)

_POLL_S = 0.02  # longest wait of the robot loop: bounds stop() latency
_OPEN_NAMES = {0: "PULSE", 1: "OPEN", 2: "CLOSE"}
_SYNC_NAMES = {0: "SYNC0", 1: "SYNC1", 2: "SYNC2"}
_KNOWN = {int(c) for c in Command}
_BAUD = {getattr(termios, f"B{b}"): b for b in (9600, 19200, 38400, 57600, 115200)}
# (transducer number, true pose) -> range in metres, or None for no echo (reported as max range).
SonarSource = Callable[[int, Pose], "float | None"]


class PioneerEmulator(DeviceThread):
    """A P2OS robot behind the pty master ``fd`` (the caller owns and closes the fd).

    - ``params``: the robot model; ``name``: the robot name reported at SYNC2.
    - ``start_pose``: true and odometry pose at power-on (m, rad); ``odometry_error``: the
      :class:`~pioneer.physics.OdometryError` of the encoders; ``motion_hook(old, new)``: the world's
      say on each step of true motion (return the allowed pose, or None to block; blocked wheels
      raise the stall bits). ``body`` replaces the whole motion model.
    - ``sonar``: per-transducer ranges (default: no echo, i.e. max range); ``sonars_per_sip`` new
      readings per SIP, polled round the ring as P2OS does.
    - ``battery``: volts, settable; ``estop_button``: the red STOP button, settable.
    - ``sip_cycle``, ``watchdog``: seconds (defaults from ``params``; shorten them in tests).
    - ``answer_config``: reply to CONFIG (its ResetBaud is 0, so ARIA keeps 9600 baud).
    - ``baud``: the host-port rate the robot listens at; bytes the host sends at another rate (as
      set on the pty) are unintelligible and dropped. None (default): any rate.
    """

    thread_name = "pioneer-emulator"

    def __init__(
        self,
        fd: int,
        params: RobotParams = P2DX,
        *,
        name: str = "asrmap-emu",
        start_pose: Pose = (0.0, 0.0, 0.0),
        odometry_error: OdometryError | None = None,
        motion_hook: MotionHook | None = None,
        body: Body | None = None,
        sonar: SonarSource | None = None,
        sonars_per_sip: int = 4,
        battery: float = 12.5,
        sip_cycle: float | None = None,
        watchdog: float | None = None,
        answer_config: bool = True,
        baud: int | None = None,
    ) -> None:
        super().__init__(fd)
        self.params = params
        self.name = name
        self.body: Body = body or DiffDrive(params, start_pose, odometry_error, motion_hook)
        self.sonar_source = sonar
        self.sonars_per_sip = sonars_per_sip
        self.battery = battery
        self.sip_cycle = params.sip_cycle if sip_cycle is None else sip_cycle
        self.watchdog = params.watchdog if watchdog is None else watchdog
        self.answer_config = answer_config
        self.baud = baud
        self.state = "waiting"
        self.sonar_on = True  # P2OS fires its sonars from OPEN on (ROS-p2os turns them off at once)
        self.encoder_stream = False
        self._counters: dict = {
            "packets": 0,
            "sips_sent": 0,
            "sessions": 0,
            "watchdog_trips": 0,
            "unknown_commands": 0,
            "ignored_before_open": 0,
            "bytes_lost": 0,
            "commands": Counter(),
        }
        self.received: deque[tuple[float, str, int | None]] = deque(maxlen=4096)
        self._estop_button = False
        self._reader = PacketReader()
        self._lock = threading.RLock()
        self._last_client = time.monotonic()
        self._watchdog_tripped = False
        self._next_sonar = 0
        self._last_step = time.monotonic()
        self._outbox: deque[tuple[float, bytes]] = deque()  # SIPs on the wire: (arrival time, bytes)

    # ---- lifecycle -------------------------------------------------------------------------------
    def _starting(self) -> None:
        self._last_step = time.monotonic()

    # ---- what tests and worlds look at -----------------------------------------------------------
    @property
    def true_pose(self) -> Pose:
        """The robot's actual pose (m, rad) in the frame of ``start_pose``."""
        return self.body.true_pose

    @property
    def odometry_pose(self) -> Pose:
        """The pose the robot's encoders integrated (m, rad): what its SIPs report."""
        return self.body.odometry_pose

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        """Measured (left, right) wheel speeds, m/s."""
        return self.body.left_speed, self.body.right_speed

    @property
    def motors_enabled(self) -> bool:
        return self.body.motors_enabled

    @property
    def estop_button(self) -> bool:
        return self._estop_button

    @estop_button.setter
    def estop_button(self, pressed: bool) -> None:
        """Press (True) or release the STOP button: pressing cuts the motors at once; they stay
        disabled after release until the client sends ENABLE 1."""
        with self._lock:
            self._estop_button = bool(pressed)
            if pressed:
                self._e_stop()

    @property
    def counters(self) -> dict:
        """Packets, SIPs sent, sessions, watchdog trips, unknown commands, ``commands`` by name, and
        the framing counts: ``bad_checksums``, ``bad_counts``, ``garbage_bytes``."""
        r = self._reader
        return {**self._counters, "bad_checksums": r.bad_checksums, "bad_counts": r.bad_counts,
                "garbage_bytes": r.bytes_skipped}

    def commands_seen(self) -> list[str]:
        """Names of the client commands received so far, in order (context-dependent for 0-2)."""
        return [name for _, name, _ in self.received]

    # ---- the robot loop --------------------------------------------------------------------------
    def _run(self) -> None:
        next_tick = time.monotonic() + self.sip_cycle
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                wake = min(next_tick, self._outbox[0][0]) if self._outbox else next_tick
                ready, _, _ = select.select([self.fd], [], [], max(0.0, min(wake - now, _POLL_S)))
                data = os.read(self.fd, 4096) if ready else b""
            except OSError as exc:
                if exc.errno not in (errno.EAGAIN, errno.EIO):  # EIO: no host has the pty open
                    log.error("emulator: reading the pty failed: %s", exc)
                    return
                data = b""
                time.sleep(_POLL_S)
            if data and self.baud is not None and self._line_baud() != self.baud:
                self._counters["bytes_lost"] += len(data)  # framing errors at the wrong rate
                data = b""
            packets = self._reader.receive(data, time.monotonic())
            if packets:
                now = time.monotonic()
                with self._lock:
                    for pkt in packets:
                        self._handle(pkt, now)
            now = time.monotonic()
            while self._outbox and self._outbox[0][0] <= now:
                self._write(self._outbox.popleft()[1])
            if now >= next_tick:
                with self._lock:
                    self._tick(now)
                next_tick = max(next_tick + self.sip_cycle, now + self.sip_cycle / 2)

    def _line_baud(self) -> int:
        try:
            speed = termios.tcgetattr(self.fd)[5]
        except (OSError, termios.error):
            return 9600
        return _BAUD.get(speed, 9600)

    def _write(self, data: bytes) -> None:
        self._counters["bytes_lost"] += self._transmit(data)

    def _tick(self, now: float) -> None:
        if (self.state == "open" and not self._watchdog_tripped and now - self._last_client > self.watchdog):
            self._watchdog_tripped = True
            self._counters["watchdog_trips"] += 1
            log.info("emulator: no client packet for %.1f s: watchdog stops the wheels", self.watchdog)
            self.body.stop()
        self.body.step(now - self._last_step)
        self._last_step = now
        if self.state == "open":
            out = frame(encode_sip(self.sip()))
            self._counters["sips_sent"] += 1
            if self.encoder_stream:
                b, conv = self.body, self.params.dist_conv
                enc = EncoderCounts(round(b.left_travel * 1000 / conv), round(b.right_travel * 1000 / conv))
                out += frame(encode_encoder(enc))
            self._outbox.append((now + len(out) * 10.0 / self._line_baud(), out))

    # ---- what the robot says ---------------------------------------------------------------------
    def sip(self) -> SIP:
        """The SIP describing the robot now (P2OS units; see :class:`pioneer.sip.SIP`)."""
        p, b = self.params, self.body
        x, y, th = b.odometry_pose
        half = round(math.pi / p.angle_conv)
        thpos = (round(th / p.angle_conv) + half) % (2 * half) - half
        heading = b.heading_target
        control = thpos if heading is None else (round(heading / p.angle_conv) + half) % (2 * half) - half
        flags = (
            (0x01 if b.motors_enabled else 0)
            | (0x1E if self.sonar_on else 0)
            | (0x20 if self._estop_button else 0)
        )
        return SIP(
            moving=bool(b.left_speed or b.right_speed),
            xpos=round(x * 1000 / p.dist_conv) & 0x7FFF,
            ypos=round(y * 1000 / p.dist_conv) & 0x7FFF,
            thpos=thpos,
            left_vel=round(b.left_speed * 1000 / p.vel_conv),
            right_vel=round(b.right_speed * 1000 / p.vel_conv),
            battery=max(0, min(255, round(self.battery * 10))),
            left_stall=b.left_stall,
            right_stall=b.right_stall,
            control=control,
            flags=flags,
            sonar=self._sonar_readings() if self.sonar_on else (),
            anport=1,
        )

    def _sonar_readings(self) -> tuple[tuple[int, int], ...]:
        p = self.params
        out = []
        for _ in range(min(self.sonars_per_sip, len(p.sonar_poses))):
            num = self._next_sonar
            self._next_sonar = (num + 1) % len(p.sonar_poses)
            metres = self.sonar_source(num, self.body.true_pose) if self.sonar_source else None
            mm = p.sonar_max_range if metres is None else min(metres * 1000, p.sonar_max_range)
            out.append((num, max(0, min(0xFFFF, round(mm / p.range_conv)))))
        return tuple(out)

    def config(self):
        """The CONFIGpac contents this robot reports (older-firmware length)."""
        p, b = self.params, self.body
        return RobotConfig(
            robot_type=p.robot_class, subtype=p.subclass, serial_number="EMU0001", reserved=0,
            rot_vel_top=round(p.max_rvelocity), trans_vel_top=round(p.max_velocity),
            rot_accel_top=round(p.rot_accel), trans_accel_top=round(p.trans_accel), pwm_max=1000,
            name=self.name, sip_cycle=round(self.sip_cycle * 1000), host_baud=0, aux1_baud=0,
            has_gripper=0, front_sonar=1, rear_sonar=1, low_battery=110, rev_count=16384,
            watchdog=round(self.watchdog * 1000), normal_mpacs=0, stall_val=200, stall_count=100,
            joy_vel=300, joy_rot_vel=50,
            rot_vel_max=round(math.degrees(b.max_w)), trans_vel_max=round(b.max_v * 1000),
            rot_accel=round(math.degrees(b.rot_accel)), rot_decel=round(math.degrees(b.rot_decel)),
            rot_kp=40, rot_kv=20, rot_ki=0,
            trans_accel=round(b.accel * 1000), trans_decel=round(b.decel * 1000),
            trans_kp=40, trans_kv=20, trans_ki=0, front_bumps=0, rear_bumps=0, has_charger=0,
            sonar_cycle=40, reset_baud=0, gyro_type=0, drift_factor=0, aux2_baud=0, aux3_baud=0,
            ticks_mm=0, shutdown_voltage=105, firmware_version="asrmap-emu P2OS",
        )

    # ---- what the client says --------------------------------------------------------------------
    def _handle(self, pkt: Packet, now: float) -> None:
        self._counters["packets"] += 1
        cmd = parse_command(pkt)
        if self.state != "open":
            name = self._handshake(cmd)
        else:
            self._last_client = now
            self._watchdog_tripped = False
            name = self._command(cmd)
        self._counters["commands"][name] += 1
        self.received.append((now, name, cmd.value))

    def _handshake(self, cmd: CommandPacket) -> str:
        c, state = cmd.cmd, self.state
        if c == 0:
            self._write(command(0))
            self.state = "sync0"
            return "SYNC0"
        if c == 1 and state == "sync0":
            self._write(command(1))
            self.state = "sync1"
            return "SYNC1"
        if c == 2 and state == "sync1":
            self._write(sync2_reply(self.name, self.params.robot_class, self.params.subclass))
            self.state = "sync2"
            return "SYNC2"
        if c == 1 and state == "sync2":
            self._open()
            return "OPEN"
        self._counters["ignored_before_open"] += 1
        return _SYNC_NAMES.get(c) or (Command(c).name if c in _KNOWN else f"unknown({c})")

    def _open(self) -> None:
        self.state = "open"
        self._counters["sessions"] += 1
        self.sonar_on = True
        self._last_client = time.monotonic()
        self._watchdog_tripped = False
        log.info("emulator: session open")

    def _close(self) -> None:
        self.body.stop()
        self.body.motors_enabled = False
        self.encoder_stream = False
        self.state = "waiting"
        log.info("emulator: session closed")

    def _e_stop(self) -> None:
        self.body.e_stop()
        self.body.motors_enabled = False

    def _command(self, cmd: CommandPacket) -> str:
        c = cmd.cmd
        if c in _OPEN_NAMES:
            if c == Command.CLOSE:
                self._close()
            return _OPEN_NAMES[c]
        if c not in _KNOWN:
            self._counters["unknown_commands"] += 1
            log.debug("emulator: unknown command %d ignored", c)
            return f"unknown({c})"
        name = Command(c).name
        handler = getattr(self, f"_cmd_{name.lower()}", None)
        if handler is not None and (cmd.value is not None or name in ("STOP", "E_STOP", "SETO")):
            handler(cmd.value)
        return name

    # One method per P2OS command acted on; integer arguments as P2OS units (mm, deg, ...).
    def _cmd_enable(self, v: int) -> None:
        self.body.motors_enabled = bool(v) and not self._estop_button

    def _cmd_seta(self, v: int) -> None:
        if v > 0:
            self.body.accel = v / 1000.0
        elif v < 0:
            self.body.decel = -v / 1000.0

    def _cmd_setra(self, v: int) -> None:
        if v > 0:
            self.body.rot_accel = math.radians(v)
        elif v < 0:
            self.body.rot_decel = math.radians(-v)

    def _cmd_setv(self, v: int) -> None:
        self.body.max_v = min(abs(v), self.params.max_velocity) / 1000.0

    def _cmd_setrv(self, v: int) -> None:
        self.body.max_w = math.radians(min(abs(v), self.params.max_rvelocity))

    def _cmd_seto(self, _v: int | None) -> None:
        self.body.reset_odometry()

    def _cmd_vel(self, v: int) -> None:
        self.body.set_velocity(v / 1000.0)

    def _cmd_rvel(self, v: int) -> None:
        self.body.set_rotation(math.radians(v))

    _cmd_rotate = _cmd_rvel

    def _cmd_vel2(self, v: int) -> None:
        left, right = vel2_wheels(v)
        k = self.params.vel2_divisor / 1000.0
        self.body.set_wheels(left * k, right * k)

    def _cmd_head(self, v: int) -> None:
        self.body.set_heading(math.radians(v))

    def _cmd_dhead(self, v: int) -> None:
        self.body.set_heading(self.body.odometry_pose[2] + math.radians(v))

    def _cmd_stop(self, _v: int | None) -> None:
        self.body.stop()

    def _cmd_e_stop(self, _v: int | None) -> None:
        self.body.e_stop()

    def _cmd_sonar(self, v: int) -> None:
        self.sonar_on = bool(v)

    def _cmd_config(self, _v: int) -> None:
        if self.answer_config:
            self._write(frame(encode_config(self.config())))

    def _cmd_encoder(self, v: int) -> None:
        self.encoder_stream = v > 0

