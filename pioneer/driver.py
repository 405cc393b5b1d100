"""Host-side P2OS driver for a Pioneer 2DX (spec p2os.md §1.3, §1.7, §1.9).

Connecting, in order (each reply waited for as in :class:`Timeouts`):

1. SYNC0, SYNC1, SYNC2, restarting from SYNC0 on a missing or wrong reply; SYNC2's reply names
   the robot (:attr:`Pioneer.identity`). A SIP instead of a reply means the robot is still open
   from an earlier session: CLOSE, let it fall quiet, and start again (ARIA's tryHarderToConnect).
2. OPEN, then VEL 0 and RVEL 0 *before* ENABLE 1: P2OS resumes the last setpoint when the motors
   are enabled, and after a reconnect the last setpoint is whatever the previous session left.
3. Optionally CONFIG 1 (the reply is :attr:`Pioneer.config`), then the first SIP.

A background thread then reads SIPs into odometry (:mod:`pioneer.odometry`), sends a PULSE whenever
nothing else was sent for ``keepalive`` seconds (so the robot's 2 s watchdog never stops a robot
whose host is alive), and watches for silence: no SIP for ``link_lost`` seconds is reported
(log, :attr:`Pioneer.link_state` = "lost", the ``on_link`` callback) and the connection is made
again with back-off. The commanded velocity is not resumed after a reconnect.

Leaving the context manager, :meth:`Pioneer.close` and any fatal error stop the robot: STOP,
ENABLE 0, CLOSE.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import serial

import serialport
from pioneer.commands import CONFIG_PAC, ENCODER_PAC, SIP_TYPES, Command, command, cstrings, vel2_arg
from pioneer.errors import CHECKS, LinkLost, PioneerError, PortUnavailable, ProtocolError
from pioneer.odometry import OdometryIntegrator, PioneerOdometry, wrap15
from pioneer.packet import Packet, PacketReader
from pioneer.params import P2DX, RobotParams
from pioneer.sip import EncoderCounts, decode_config, decode_encoder, decode_sip

log = logging.getLogger(__name__)

P2OS_BAUDS = (9600, 19200, 38400, 57600, 115200)  # HOSTBAUD codes 0-4 (spec §1.9)


@dataclass(frozen=True)
class Timeouts:
    """Seconds the driver waits; defaults follow ARIA (spec §1.3, §1.9).

    - ``sync_reply``: per SYNC reply (ARIA 1 s, ROS-p2os 0.2 s); ``sync_attempts``: unanswered
      SYNCs before giving up (ARIA gives up after 10).
    - ``close_settle``: after CLOSE to a robot left open, before syncing again.
    - ``config``: wait for the CONFIGpac (ARIA 1 s); ``first_sip``: after OPEN.
    - ``keepalive``: PULSE when nothing was sent for this long (ARIA 0.5 s; P2OS watchdog 2 s).
    - ``link_lost``: no SIP for this long means the link is lost (five SIP cycles: a lost robot is
      noticed within 0.5 s, well inside the 1 s a field robot may run unsupervised).
    - ``reconnect_min``/``reconnect_max``: back-off between reconnection attempts, doubling.
    - ``read``: serial read timeout; bounds how fast the thread notices close() and silences.
    """

    sync_reply: float = 1.0
    sync_attempts: int = 10
    close_settle: float = 0.3
    config: float = 1.0
    first_sip: float = 1.0
    keepalive: float = 0.5
    link_lost: float = 0.5
    reconnect_min: float = 0.25
    reconnect_max: float = 5.0
    read: float = 0.02


@dataclass(frozen=True)
class Identity:
    """What the robot said in reply to SYNC2: its name, class and subclass (e.g. Pioneer, p2dx)."""

    name: str
    robot_class: str
    subclass: str


class _Closing(Exception):
    """close() interrupted a wait."""


def open_port(port: str, baudrate: int, read_timeout: float = 0.02) -> serial.SerialBase:
    """``port`` (a device or any ``serial.serial_for_url`` URL) at ``baudrate``, 8N1, raw, locked
    exclusively (:func:`serialport.open_port`).

    Raises :class:`PortUnavailable` naming the cause (missing, permission, busy and by whom) and the fix."""
    try:
        return serialport.open_port(port, baudrate, timeout=read_timeout, write_timeout=1.0,
                                    what="the Pioneer")
    except serialport.PortError as exc:
        raise PortUnavailable(str(exc)) from exc


class Pioneer:
    """A Pioneer 2DX on ``port`` (anything ``serial.serial_for_url`` opens), connected on creation.

    - ``params``: the robot model (:data:`pioneer.params.P2DX`); ``timeouts``: :class:`Timeouts`.
    - ``request_config``: ask for the CONFIGpac while connecting (:attr:`config`).
    - ``history``: how many odometry records :meth:`history` keeps.
    - ``on_link(state, reason)``: called on every change of :attr:`link_state`
      ("connecting", "up", "lost", "closed").
    - ``reconnect``: reconnect in the background after a lost link (else the state stays "lost").
    - ``enable_motors``: send ENABLE 1 on every (re)connect (False for a look-only connection).
    - ``low_battery``: volts below which :attr:`alerts` reports a low battery (P2OS's own
      CONFIGpac LowBattery is 11.0 V on a P2DX; it shuts down near 10.5 V).

    Raises :class:`~pioneer.errors.PortUnavailable`, :class:`~pioneer.errors.LinkLost` or
    :class:`~pioneer.errors.ProtocolError` when the first connection fails.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 9600,
        params: RobotParams = P2DX,
        *,
        timeouts: Timeouts | None = None,
        request_config: bool = False,
        history: int = 600,
        on_link: Callable[[str, str], Any] | None = None,
        reconnect: bool = True,
        enable_motors: bool = True,
        low_battery: float = 11.0,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self.params = params
        self.timeouts = timeouts or Timeouts()
        self.request_config = request_config
        self.reconnect = reconnect
        self.enable_motors = enable_motors
        self.low_battery = low_battery
        self._alerts: tuple[str, ...] = ()
        self.identity: Identity | None = None
        self.config = None
        self.encoders: EncoderCounts | None = None
        self.link_state = "connecting"
        self.error: BaseException | None = None
        #: Test hook: False stops the PULSE keep-alive (the robot's watchdog then stops it).
        self.keepalive_enabled = True
        self._on_link = on_link
        self._odometry_callbacks: list[Callable[[PioneerOdometry], Any]] = []
        self._odometry: PioneerOdometry | None = None
        self._history: deque[PioneerOdometry] = deque(maxlen=history)
        self._cond = threading.Condition()
        self._wlock = threading.Lock()
        self._closing = threading.Event()
        self._reader = PacketReader()
        self._pending: deque[tuple[Packet, float]] = deque()
        self._integrator = OdometryIntegrator(params)
        self._seto_deadline: float | None = None
        self._last_sent = 0.0
        self._last_sip = 0.0
        self._port_broken = False  # a read or write failed: reopen the port before reconnecting
        self._count = dict.fromkeys(
            ("sips", "bad_sips", "other_packets", "reconnects", "links_lost", "handshake_closes",
             "keepalives", "callback_errors"), 0)
        self._ser = open_port(port, baudrate, self.timeouts.read)
        try:
            self._session()
        except BaseException:
            self._ser.close()
            self._set_state("closed", "the first connection failed")
            raise
        self._thread = threading.Thread(target=self._run, name=f"pioneer-{port}", daemon=True)
        self._thread.start()

    # ---- public: state -----------------------------------------------------------------------------
    @property
    def odometry(self) -> PioneerOdometry | None:
        """The latest odometry record (odometry frame; see :class:`PioneerOdometry`)."""
        return self._odometry

    def history(self) -> list[PioneerOdometry]:
        """The most recent odometry records, oldest first."""
        with self._cond:
            return list(self._history)

    def on_odometry(self, callback: Callable[[PioneerOdometry], Any]) -> None:
        """Call ``callback(record)`` from the reader thread for every SIP. Keep it short: the
        thread also sends the keep-alive. Exceptions are logged and counted, never fatal."""
        self._odometry_callbacks.append(callback)

    def wait_odometry(self, timeout: float, after: float | None = None) -> PioneerOdometry | None:
        """Block until a record newer than ``after`` (its ``t``; default: the latest now) arrives;
        None on timeout."""
        with self._cond:
            since = after if after is not None else (self._odometry.t if self._odometry else -math.inf)
            self._cond.wait_for(lambda: self._odometry is not None and self._odometry.t > since, timeout)
            odo = self._odometry
            return odo if odo is not None and odo.t > since else None

    @property
    def alerts(self) -> tuple[str, ...]:
        """What the latest SIP says is wrong with the robot, each with its remedy: the e-stop
        pressed, motors disabled, battery low (empty when all is well)."""
        return self._alerts

    def _check_sip(self, sip) -> None:
        alerts = []
        if sip.e_stop:
            alerts.append("Pioneer e-stop pressed: the motors are cut; release the red STOP button, then "
                          "press the MOTORS button on the robot's panel")
        elif self.enable_motors and not sip.motors_enabled and self.link_state == "up":
            alerts.append("Pioneer motors disabled although ENABLE 1 was sent: press the MOTORS button on "
                          "the robot's panel (check the motor power switch and that the e-stop is released)")
        volts = sip.battery_volts
        if 0 < volts < self.low_battery:
            alerts.append(f"Pioneer battery low: {volts:.1f} V (below {self.low_battery:.1f} V): charge or "
                          "swap the battery (P2OS shuts down near 10.5 V)")
        alerts_t = tuple(alerts)
        if alerts_t != self._alerts:
            for a in alerts_t:
                if a not in self._alerts:
                    log.warning("pioneer %s: %s", self.port, a)
            for a in self._alerts:
                if a not in alerts_t:
                    log.info("pioneer %s: cleared: %s", self.port, a.split(":")[0])
            self._alerts = alerts_t

    @property
    def counters(self) -> dict[str, int]:
        """SIPs, reader counts (bad checksums, garbage bytes), reconnects and more, as a snapshot."""
        r = self._reader
        return {
            **self._count,
            "packets": r.packets_ok,
            "bad_checksums": r.bad_checksums,
            "bad_counts": r.bad_counts,
            "garbage_bytes": r.bytes_skipped,
        }

    # ---- public: commands (SI units; robot frame: x forward, theta counter-clockwise) --------------
    def set_velocity(self, v: float, w: float) -> tuple[float, float]:
        """Drive at ``v`` m/s and turn at ``w`` rad/s (VEL mm/s, RVEL deg/s), clamped to the robot's
        limits. Returns what was commanded after clamping and rounding. Raises LinkLost if not up."""
        self._require_up()
        vel = round(max(-self.params.max_velocity, min(self.params.max_velocity, v * 1000.0)))
        rvel = round(max(-self.params.max_rvelocity, min(self.params.max_rvelocity, math.degrees(w))))
        self._send(command(Command.VEL, vel) + command(Command.RVEL, rvel))
        return vel / 1000.0, math.radians(rvel)

    def set_wheel_velocities(self, left: float, right: float) -> tuple[float, float]:
        """Drive each wheel at its own speed (m/s) with VEL2 (Vel2Divisor mm/s steps, clamped to the
        robot's limit). Returns the speeds commanded. Raises LinkLost if not up."""
        self._require_up()
        p = self.params
        top = min(p.max_velocity, 127 * p.vel2_divisor)

        def units(speed: float) -> int:
            return round(max(-top, min(top, speed * 1000.0)) / p.vel2_divisor)

        lu, ru = units(left), units(right)
        self._send(command(Command.VEL2, vel2_arg(lu, ru)))
        return lu * p.vel2_divisor / 1000.0, ru * p.vel2_divisor / 1000.0

    def stop(self) -> bool:
        """STOP: decelerate to a standstill. Best effort: False if the command could not be written."""
        return self._send_anyway(Command.STOP)

    def e_stop(self) -> bool:
        """E_STOP: stop at once, overriding the deceleration limit. Best effort, like :meth:`stop`."""
        return self._send_anyway(Command.E_STOP)

    def _send_anyway(self, cmd: Command) -> bool:
        # Stopping must be tried whatever the link state (a robot still listening will obey).
        try:
            self._send(command(cmd))
            return True
        except PioneerError as exc:
            log.warning("could not send %s: %s", cmd.name, exc)
            return False

    def sonar(self, on: bool) -> None:
        """Turn the sonar ring on or off (SONAR 1/0)."""
        self._require_up()
        self._send(command(Command.SONAR, int(bool(on))))

    def reset_odometry(self) -> None:
        """SETO: the robot's position becomes (0, 0, 0), and so does the odometry frame's origin: the
        records after the robot's reset start at (0, 0, 0) at the current pose."""
        self._require_up()
        self._seto_deadline = time.monotonic() + 3 * self.params.sip_cycle + self.timeouts.read
        self._send(command(Command.SETO))

    def close(self) -> None:
        """Stop the robot (STOP, ENABLE 0), CLOSE the session and the port. Idempotent."""
        if self.link_state == "closed" and not self._ser.is_open:
            return
        self._closing.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(5.0)
        self._shutdown_robot()
        self._set_state("closed", "closed by the host")

    def __enter__(self) -> Pioneer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- I/O -----------------------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        with self._wlock:
            try:
                self._ser.write(data)
            except (serial.SerialException, OSError) as exc:
                self._port_broken = True
                raise LinkLost(f"writing to {self.port} failed: {exc}; {CHECKS}") from exc
            self._last_sent = time.monotonic()

    def _require_up(self) -> None:
        if self.link_state != "up":
            raise LinkLost(f"the Pioneer on {self.port} is {self.link_state}: command not sent")

    def _read(self) -> list[tuple[Packet, float]]:
        """Whatever packets the next read completes, each stamped with the time its first byte left
        the robot: the read's time minus the transfer time at the baud of the packet and of every byte
        that followed it in the read (a 31-byte SIP is 32 ms at 9600 baud), on the host's
        ``time.monotonic()`` clock as the laser's scans are."""
        if self._closing.is_set():
            raise _Closing
        try:
            data = self._ser.read(max(1, self._ser.in_waiting))
        except (serial.SerialException, OSError, TypeError) as exc:
            # pyserial raises TypeError/SerialException when the device vanishes mid-read.
            self._port_broken = True
            raise LinkLost(f"reading {self.port} failed: {exc}; {CHECKS}") from exc
        t = time.monotonic()
        packets = self._reader.receive(data, t)
        if not packets:
            return []
        if not data:
            t = self._reader.last_rx  # expired: what the stalled bytes held arrived by the last read
        per_byte = 10.0 / (self._ser.baudrate or self.baudrate)  # 8N1: ten bits a byte
        # A late read (USB latency, a busy host) completes several SIPs at once. They were sent one
        # after the other, so each ends where the next begins: stamping them all from the read's time
        # would put them microseconds apart and make any velocity taken between them absurd.
        end = t - self._reader.pending * per_byte
        stamped = []
        for p in reversed(packets):
            end -= (len(p.data) + 5) * per_byte
            stamped.append((p, end))
        return stamped[::-1]

    def _next_packet(self, timeout: float) -> Packet | None:
        deadline = time.monotonic() + timeout
        while not self._pending:
            if time.monotonic() >= deadline:
                return None
            self._pending.extend(self._read())
        return self._pending.popleft()[0]

    def _flush_input(self) -> None:
        try:
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass
        self._reader.clear()
        self._pending.clear()

    def _set_state(self, state: str, reason: str) -> None:
        if state == self.link_state:
            return
        self.link_state = state
        (log.warning if state == "lost" else log.info)("pioneer %s: %s (%s)", self.port, state, reason)
        if self._on_link is not None:
            try:
                self._on_link(state, reason)
            except Exception:
                self._count["callback_errors"] += 1
                log.exception("on_link callback failed")

    # ---- connecting -------------------------------------------------------------------------------
    def _handshake(self) -> Identity:
        t = self.timeouts
        step, unanswered, closes = 0, 0, 0
        while True:
            self._flush_input()
            self._send(command(step))
            reply = self._next_packet(t.sync_reply)
            while reply is not None and step > 0 and reply.type == step - 1:
                reply = self._next_packet(t.sync_reply)  # a late duplicate of the previous echo
            if reply is None:
                unanswered += 1
                if unanswered >= t.sync_attempts:
                    raise self._no_answer(unanswered)
                step = 0
            elif reply.type == step == 2:
                return Identity(*cstrings(reply.payload, 3))
            elif reply.type == step:
                step += 1
            elif reply.type in SIP_TYPES:
                closes += 1
                self._count["handshake_closes"] += 1
                if closes > t.sync_attempts:
                    raise ProtocolError(
                        f"the robot on {self.port} keeps sending SIPs after {closes - 1} CLOSE commands; "
                        "power-cycle it (or reset it with the RESET button) and try again"
                    )
                log.info("pioneer %s: robot still open from an earlier session: sending CLOSE", self.port)
                self._send(command(Command.CLOSE))
                time.sleep(t.close_settle)
                step = 0
            else:
                log.debug("pioneer %s: SYNC%d answered by packet type 0x%02x: restarting", self.port,
                          step, reply.type)
                step = 0

    def _no_answer(self, attempts: int) -> LinkLost:
        c = self.counters
        if c["garbage_bytes"] or c["bad_checksums"]:
            seen = (f"{c['garbage_bytes']} bytes arrived that are not P2OS packets "
                    f"({c['bad_checksums']} bad checksums): probably the wrong baud")
        else:
            seen = "nothing arrived"
        others = [b for b in P2OS_BAUDS if b != self.baudrate]
        found = self._autobaud(others)
        if found is not None:
            return LinkLost(
                f"no P2OS robot answered on {self.port} at {self.baudrate} baud, but one answered SYNC0 at "
                f"{found} baud: set the baud to {found} (pioneer.baudrate in the config)")
        return LinkLost(
            f"no P2OS robot answered on {self.port} at {self.baudrate} baud: expected the SYNC echo "
            f"(fa fb 03 00 00 00) after {attempts} attempts, {seen}; nor at any other P2OS baud "
            f"({', '.join(map(str, others))}); {CHECKS}"
        )

    def _autobaud(self, bauds: list[int]) -> int | None:
        """The first of ``bauds`` at which the robot echoes SYNC0 (one try each), or None; the port
        is left at :attr:`baudrate`."""
        try:
            for baud in bauds:
                try:
                    self._ser.baudrate = baud
                except (ValueError, serial.SerialException, OSError):
                    continue
                self._flush_input()
                self._send(command(0))
                reply = self._next_packet(min(0.3, self.timeouts.sync_reply))
                if reply is not None and reply.type == 0:
                    log.warning("pioneer %s: the robot answers at %d baud, not %d", self.port, baud,
                                self.baudrate)
                    self._send(command(Command.CLOSE))  # leave it waiting for a client, as found
                    return baud
        except (PioneerError, serial.SerialException, OSError):
            pass
        finally:
            try:
                self._ser.baudrate = self.baudrate
            except (ValueError, serial.SerialException, OSError):
                pass
            self._flush_input()
        return None

    def _session(self) -> None:
        """Handshake, OPEN, zero velocity, ENABLE, (CONFIG), first SIP; raises when it fails."""
        self._set_state("connecting", "handshake")
        ident = self._handshake()
        if self.identity is None or ident != self.identity:
            log.info("pioneer %s: connected to %r, %s %s", self.port, ident.name, ident.robot_class,
                     ident.subclass)
        if ident.subclass.lower() != self.params.subclass.lower():
            log.warning("pioneer %s: robot reports subclass %r but the parameters are for %r; "
                        "odometry scales may be wrong", self.port, ident.subclass, self.params.subclass)
        self.identity = ident
        self._integrator.rebase()
        self._seto_deadline = None
        zero = command(Command.VEL, 0) + command(Command.RVEL, 0)
        self._send(command(Command.OPEN) + zero + (command(Command.ENABLE, 1) if self.enable_motors else b""))
        if self.request_config:
            self._send(command(Command.CONFIG, 1))
            self._pump_until(lambda: self.config is not None, self.timeouts.config)
            if self.config is None:
                log.info("pioneer %s: no CONFIG reply (optional)", self.port)
        sips = self._count["sips"]
        self._pump_until(lambda: self._count["sips"] > sips, self.timeouts.first_sip)
        if self._count["sips"] == sips:
            raise LinkLost(
                f"the robot on {self.port} answered the handshake but sent no SIP within "
                f"{self.timeouts.first_sip:.1f} s of OPEN; power-cycle it and try again"
            )
        self._set_state("up", f"{ident.name} ({ident.robot_class} {ident.subclass})")

    # ---- the reader thread ----------------------------------------------------------------------------
    def _pump_until(self, done: Callable[[], bool], timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            while self._pending:
                self._dispatch(*self._pending.popleft())
            for pkt, t in self._read():
                self._dispatch(pkt, t)

    def _dispatch(self, pkt: Packet, t: float) -> None:
        kind = pkt.type
        try:
            if kind in SIP_TYPES:
                self._on_sip(pkt, t)
            elif kind == CONFIG_PAC:
                self.config = decode_config(pkt.data)
            elif kind == ENCODER_PAC:
                self.encoders = decode_encoder(pkt.data)
            else:
                self._count["other_packets"] += 1
        except ProtocolError as exc:
            self._count["bad_sips" if kind in SIP_TYPES else "other_packets"] += 1
            log.debug("pioneer %s: %s", self.port, exc)

    def _on_sip(self, pkt: Packet, t: float) -> None:
        sip = decode_sip(pkt.data)
        self._count["sips"] += 1
        self._last_sip = time.monotonic()
        self._check_sip(sip)
        if self._odometry is not None and t <= self._odometry.t:
            t = self._odometry.t + 1e-6  # two SIPs completed by one read: keep the stamps increasing
        if self._seto_deadline is not None:
            # SIPs sent before the robot executed SETO still carry the old position; the first one
            # near the origin (or the deadline) starts the new frame.
            near = abs(wrap15(sip.xpos)) < 512 and abs(wrap15(sip.ypos)) < 512
            if not near and t < self._seto_deadline:
                return
            self._seto_deadline = None
            self._integrator.reset()
        odo = self._integrator.update(sip, t)
        with self._cond:
            self._odometry = odo
            self._history.append(odo)
            self._cond.notify_all()
        for cb in self._odometry_callbacks:
            try:
                cb(odo)
            except Exception:
                self._count["callback_errors"] += 1
                log.exception("on_odometry callback failed")

    def _run(self) -> None:
        try:
            while not self._closing.is_set():
                try:
                    self._serve()
                except LinkLost as exc:
                    self._count["links_lost"] += 1
                    self._set_state("lost", str(exc))
                if not self.reconnect:
                    self._closing.wait()
                    return
                self._reconnect()
        except _Closing:
            return
        except Exception as exc:  # a bug, not a link problem: stop the robot rather than drive blind
            self.error = exc
            log.exception("pioneer %s: driver thread failed; stopping the robot", self.port)
            self._shutdown_robot()
            self._set_state("closed", f"driver error: {exc}")

    def _serve(self) -> None:
        """Read SIPs and keep the robot's watchdog fed until the link is lost (LinkLost)."""
        t = self.timeouts
        self._last_sip = time.monotonic()
        while True:
            for pkt, stamp in self._read():
                self._dispatch(pkt, stamp)
            now = time.monotonic()
            silent = now - self._last_sip
            if silent > t.link_lost:
                raise LinkLost(f"no SIP from the robot on {self.port} for {silent:.1f} s; {CHECKS}")
            if self.keepalive_enabled and now - self._last_sent >= t.keepalive:
                self._send(command(Command.PULSE))
                self._count["keepalives"] += 1

    def _reconnect(self) -> None:
        delay = self.timeouts.reconnect_min
        while not self._closing.wait(delay):
            try:
                if self._port_broken or not self._ser.is_open:
                    self._ser.close()
                    self._ser = open_port(self.port, self.baudrate, self.timeouts.read)
                    self._port_broken = False
                self._session()
                self._count["reconnects"] += 1
                return
            except (LinkLost, ProtocolError) as exc:
                log.warning("pioneer %s: reconnecting failed (next try in %.1f s): %s", self.port,
                            min(2 * delay, self.timeouts.reconnect_max), exc)
                delay = min(2 * delay, self.timeouts.reconnect_max)

    def _shutdown_robot(self) -> None:
        """STOP, ENABLE 0, CLOSE (ARIA's disconnect order), then close the port; never raises."""
        if not self._ser.is_open:
            return
        try:
            self._send(command(Command.STOP) + command(Command.ENABLE, 0) + command(Command.CLOSE))
            self._ser.flush()
        except (PioneerError, serial.SerialException, OSError) as exc:
            log.warning("pioneer %s: could not stop the robot on close: %s", self.port, exc)
        finally:
            try:
                self._ser.close()
            except (serial.SerialException, OSError):
                pass
