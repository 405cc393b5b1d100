"""Host-side SICK LMS2xx reader: start-up, continuous scans, recovery (spec lms2xx.md §2.6-2.7).

Start-up, in order (each step waits for its reply; timeouts in :class:`Timeouts`):

1. find the device's baud: at 9600/19200/38400/500000 send ``20 25`` (stop output) and expect 0xA0;
2. optionally reset (``10`` -> 0x91, then the 0x90 power-on telegram at 9600, up to 60 s);
3. switch to the requested baud (``20 4x``: the reply comes at the old rate, then the port follows);
4. read the type (``3A``), enter installation mode (``20 00 SICK_LMS``), set the variant (``3B``),
   read the configuration (``74``) and write it back with our units and measuring mode (``77``);
5. continuous output (``20 24``), then 0xB0 telegrams are decoded by a background thread.

A silence longer than the expected scan period plus a margin, or a 0x90 power-on telegram, means
the device rebooted or the link broke: the thread runs the whole start-up again (the device is
back at 9600) and reports the event. ``close()`` stops the output and returns the device to 9600.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import serial

import serialport
from laser import protocol as p
from laser.errors import CHECKS, ConfigError, LaserError, LinkLost, ProtocolError
from laser.telegram import FrameReader, Telegram, request
from laser.timing import scan_period, sweep_time, transmit_time
from laser.values import LaserScan, decode_b0

log = logging.getLogger(__name__)

BAUDS = (9600, 19200, 38400, 500000)
_READ_S = 0.05  # serial read timeout: bounds how fast the thread notices close() and silences


@dataclass(frozen=True)
class Timeouts:
    """Seconds the reader waits. Defaults follow the real device and sicktoolbox (spec §2.2, §2.6).

    - ``probe``: per baud while searching (the LMS answers within 60 ms; extended by one longest
      telegram's transmission time when bytes are arriving).
    - ``reply``: an ordinary request. ``config``: 0x77 (an EEPROM write; sicktoolbox 15 s).
    - ``reset``: from 0x10 to the 0x90 power-on telegram (sicktoolbox 60 s).
    - ``connect``: keep searching the bauds this long before giving up (0: one pass).
    - ``settle``: after changing the port's baud (sicktoolbox sleeps 250 ms).
    - ``scan_margin``: silence beyond the expected scan period that counts as a lost link.
    - ``recover``: each recovery attempt searches this long (a power-cycled LMS needs ~35 s).
    """

    probe: float = 0.3
    reply: float = 2.0
    config: float = 15.0
    reset: float = 60.0
    connect: float = 0.0
    settle: float = 0.25
    scan_margin: float = 0.5
    recover: float = 60.0


@dataclass(frozen=True)
class LinkEvent:
    """A change of :attr:`LMS2xx.link_state`: ``t`` host monotonic seconds, ``state`` the new state
    ("starting", "up", "lost", "down", "closed"), ``reason`` what happened, in words."""

    t: float
    state: str
    reason: str


class _Closing(Exception):
    """Raised inside the start-up when close() interrupts it."""


class LMS2xx:
    """An LMS200/LMS2xx on ``port`` (anything ``serial.serial_for_url`` opens).

    ``baudrate`` is the rate to run at; the device's current rate is found by trying all four.
    ``resolution`` (degrees: 1.0, 0.5, 0.25) and ``fov`` (degrees: 180, 100) select the variant;
    ``units`` ("mm", "cm", "10cm") and ``mode`` (measuring mode, spec §2.3; 5 = ARIA's 32 m with one
    reflector bit) go into the configuration. The constructor runs the start-up and starts the
    reader thread; scans are then available by iteration, :meth:`read` and :meth:`on_scan`.
    Errors: :class:`~laser.errors.LinkLost`, :class:`~laser.errors.ProtocolError`,
    :class:`~laser.errors.ConfigError`.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 38400,
        *,
        resolution: float = 1.0,
        fov: int = 180,
        units: str = "mm",
        mode: int = 5,
        reset: bool = False,
        timeouts: Timeouts | None = None,
        recover: bool = True,
        queue_size: int = 100,
    ) -> None:
        cdeg = round(resolution * 100)
        if baudrate not in BAUDS:
            raise ConfigError(f"baudrate {baudrate} is not an LMS2xx rate; use one of {BAUDS}")
        if cdeg not in p.VARIANTS.get(fov, ()):
            raise ConfigError(
                f"the LMS2xx has no {fov} deg / {resolution} deg variant; use 180 deg at 1 or 0.5, "
                "or 100 deg at 1, 0.5 or 0.25"
            )
        if units not in p.UNITS:
            raise ConfigError(f"units {units!r}: use one of {sorted(p.UNITS)}")
        if mode not in p.RANGE_BITS:
            raise ConfigError(
                f"measuring mode 0x{mode:02X} gives no ranges; use one of {sorted(p.RANGE_BITS)}"
            )
        self.port = port
        self.target_baud = baudrate
        self.fov = fov
        self.resolution = cdeg / 100.0
        self.units = units
        self.mode = mode
        self.timeouts = timeouts or Timeouts()
        self.recover = recover
        self.count = round(fov / self.resolution) + 1
        self.device_type = ""
        self.detected_baud: int | None = None
        self.config: p.ConfigBlock | None = None
        self.link_state = "starting"
        self.last_error: Exception | None = None
        self._reset_first = reset
        self._framer = FrameReader()
        self._stats = {"scans": 0, "bad_scans": 0, "link_lost": 0, "reboots": 0, "recoveries": 0,
                       "stamps_corrected": 0}
        self._sweep = sweep_time(fov, self.resolution)
        self._last_stamp = -float("inf")
        self._power_on_seen = False
        self._scans: deque[LaserScan] = deque(maxlen=queue_size)
        self._cond = threading.Condition()
        self._scan_callbacks: list[Callable[[LaserScan], None]] = []
        self._link_callbacks: list[Callable[[LinkEvent], None]] = []
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_scan = time.monotonic()
        try:
            self._ser = serialport.open_port(port, baudrate, timeout=_READ_S, write_timeout=2.0,
                                             what="the LMS2xx")
        except serialport.PortError as exc:
            raise LinkLost(str(exc)) from exc
        try:
            self._startup(time.monotonic() + self.timeouts.connect, reset=reset)
        except BaseException:
            self._ser.close()
            self.link_state = "closed"
            raise
        self._thread = threading.Thread(target=self._run, name=f"lms2xx {port}", daemon=True)
        self._thread.start()

    # ---- public ---------------------------------------------------------------------------------
    @property
    def baudrate(self) -> int:
        """The rate the port (and, while the link is up, the device) runs at now."""
        return self._ser.baudrate

    @property
    def counters(self) -> dict[str, int]:
        """Telegrams ok, bad CRCs, oversize lengths, bytes skipped, ACK/NAK seen, scans, bad scans,
        link losses, reboots (device found back at power-on state) and recoveries."""
        return self._framer.counters.as_dict() | self._stats

    @property
    def expected_period(self) -> float:
        """Seconds between scans the device can reach at this baud and resolution."""
        return scan_period(self.count, self.resolution, self.baudrate)

    def on_scan(self, callback: Callable[[LaserScan], None]) -> None:
        """Call ``callback(scan)`` from the reader thread for every scan (exceptions are logged)."""
        self._scan_callbacks.append(callback)

    def on_link(self, callback: Callable[[LinkEvent], None]) -> None:
        """Call ``callback(event)`` from the reader thread on every link state change."""
        self._link_callbacks.append(callback)

    def read(self, timeout: float | None = None) -> LaserScan | None:
        """The oldest queued scan, waiting up to ``timeout`` s (None: forever); None on timeout or
        after close(). Raises LinkLost if the link is down for good (``recover=False``)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._scans:
                if self.link_state == "down":
                    raise LinkLost(f"the LMS2xx on {self.port} stopped answering: {self.last_error}")
                if self.link_state == "closed":
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._scans.popleft()

    def __iter__(self) -> Iterator[LaserScan]:
        """Scans until close(), waiting through link recoveries."""
        while (scan := self.read()) is not None:
            yield scan

    def close(self) -> None:
        """Stop the thread, stop continuous output (``20 25``), return the device to 9600 (``20 42``)
        and close the port. Never raises for a device that no longer answers."""
        if self.link_state == "closed":
            return
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        was_up = self.link_state == "up"
        if was_up:
            self._closing.clear()  # let the farewell requests run
            try:
                self._request(p.SWITCH_MODE, p.ON_REQUEST, timeout=self.timeouts.reply)
                if self.baudrate != p.POWER_ON_BAUD:
                    self._switch_baud(p.POWER_ON_BAUD)
            except (LaserError, serial.SerialException, OSError) as exc:
                log.warning("LMS2xx on %s: could not stop it and return it to 9600 baud: %s", self.port, exc)
            self._closing.set()
        self._ser.close()
        self._set_link("closed", "closed by the host")

    def __enter__(self) -> LMS2xx:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- start-up -------------------------------------------------------------------------------
    def _startup(self, deadline: float, *, reset: bool = False) -> None:
        self._set_link("starting", f"start-up on {self.port}")
        self._power_on_seen = False
        self.detected_baud = self._find_baud(deadline)
        if reset:
            self._reset()
        if self.baudrate != self.target_baud:
            self._switch_baud(self.target_baud)
        typ = self._request(p.REQUEST_TYPE)
        self.device_type = typ.data.decode("ascii", "replace").strip("\0 ")
        password = p.password_for(self.device_type)
        answer = self._request(p.SWITCH_MODE, p.INSTALLATION, password)
        if answer.data[:1] != bytes((p.MODE_OK,)):
            raise ProtocolError(
                f"the LMS2xx refused installation mode with password {password.decode()} "
                f"(reply A0 {answer.data.hex(' ')}); check the device type ({self.device_type!r})"
            )
        self._set_variant()
        self._configure()
        answer = self._request(p.SWITCH_MODE, p.CONTINUOUS)
        if answer.data[:1] != bytes((p.MODE_OK,)):
            raise ProtocolError(f"the LMS2xx refused continuous output (reply A0 {answer.data.hex(' ')})")
        self._last_scan = time.monotonic()
        self._set_link(
            "up",
            f"{self.device_type} at {self.baudrate} baud, {self.fov} deg / {self.resolution} deg, "
            f"{self.units}, mode {self.mode}",
        )

    def _find_baud(self, deadline: float) -> int:
        """Try each baud (the one in use first, then the requested, then power-on 9600, ...) until
        the device answers ``20 25``; keep going round until ``deadline``."""
        order = list(dict.fromkeys([self.baudrate, self.target_baud, p.POWER_ON_BAUD, *BAUDS]))
        heard: dict[int, int] = {}
        while True:
            for baud in order:
                try:
                    self._set_port_baud(baud)
                except (ValueError, serial.SerialException) as exc:
                    heard[baud] = -1
                    log.debug("port %s cannot run at %d baud: %s", self.port, baud, exc)
                    continue
                got = self._probe(baud)
                if got is True:
                    log.info("LMS2xx on %s answered at %d baud", self.port, baud)
                    return baud
                heard[baud] = heard.get(baud, 0) + got
            if time.monotonic() >= deadline:
                break
        summary = ", ".join(
            f"{b}: " + ("port refused the rate" if n < 0 else f"{n} bytes, no telegram")
            for b, n in heard.items()
        )
        if heard.get(500000) == -1:
            # An LMS left at 500000 by an earlier session only answers there until power-cycled.
            raise LinkLost(
                f"no LMS2xx answer on {self.port} at {'/'.join(str(b) for b in order if b != 500000)} baud, "
                f"and the adapter cannot run at 500000 baud ({summary}): if the LMS was set to 500000, "
                f"{serialport.unsupported_baud(self.port, 500000)}; otherwise {CHECKS}"
            )
        raise LinkLost(
            f"no LMS2xx answer on {self.port}: expected reply A0 to '20 25' at {'/'.join(map(str, order))} "
            f"baud; received {summary}; {CHECKS}"
        )

    def _probe(self, baud: int) -> bool | int:
        """True if a device telegram arrives after ``20 25`` at ``baud``, else the bytes heard."""
        self._flush()
        self._ser.write(request(p.SWITCH_MODE, p.ON_REQUEST))
        start = time.monotonic()
        deadline = start + self.timeouts.probe
        # A telegram already under way (a scan at 9600 takes up to 0.8 s) delays the answer.
        extended = deadline + transmit_time(812 + 7, baud)
        heard = 0
        seen_device = False
        while (now := time.monotonic()) < (extended if heard else deadline):
            self._check_closing()
            chunk = self._ser.read(self._ser.in_waiting or 1)
            heard += len(chunk)
            for tg in self._framer.feed(chunk):
                if tg.command == p.POWER_ON:
                    self._power_on_seen = True
                if tg.command == p.SWITCH_MODE | 0x80:
                    return True
                seen_device |= tg.is_reply
            if seen_device and now > deadline:
                return True  # it talks at this baud; the next request stops the stream
        return True if seen_device else heard

    def _reset(self) -> None:
        self._request(p.RESET, expect=p.RESET_CONFIRM)
        log.info(
            "LMS2xx on %s reset; waiting up to %.0f s for its power-on telegram",
            self.port,
            self.timeouts.reset,
        )
        self._set_port_baud(p.POWER_ON_BAUD)
        self._wait_for(p.POWER_ON, self.timeouts.reset, "0x90 power-on telegram after reset (10)")
        self._power_on_seen = True

    def _switch_baud(self, baud: int) -> None:
        answer = self._request(p.SWITCH_MODE, p.BAUD_MODES[baud])
        if answer.data[:1] != bytes((p.MODE_OK,)):
            raise ConfigError(
                f"the LMS2xx refused {baud} baud (reply A0 {answer.data.hex(' ')})"
                + ("; 500000 baud needs an RS-422 interface" if baud == 500000 else "")
            )
        self._set_port_baud(baud)

    def _set_port_baud(self, baud: int) -> None:
        if self._ser.baudrate != baud:
            self._ser.baudrate = baud
            self._sleep(self.timeouts.settle)
        self._flush()

    def _set_variant(self) -> None:
        want = round(self.resolution * 100)
        answer = p.VariantReply.parse(self._request(p.SWITCH_VARIANT, p.variant_data(self.fov, want)).data)
        if not answer.accepted or (answer.fov, answer.resolution_cdeg) != (self.fov, want):
            raise ConfigError(
                f"the LMS2xx refused the variant {self.fov} deg / {self.resolution} deg (it reports "
                f"{answer.fov} deg / {answer.resolution_cdeg / 100} deg); check its type "
                f"({self.device_type!r}) supports it"
            )

    def _configure(self) -> None:
        try:
            base = p.ConfigBlock(self._request(p.REQUEST_CONFIG).data)
        except LinkLost:
            log.warning(
                "LMS2xx on %s did not report its configuration (74); writing a default block", self.port
            )
            base = p.ConfigBlock.default()
        wanted = base.with_settings(mode=self.mode, units=self.units)
        if wanted.raw != base.raw:
            answer = self._request(p.CONFIGURE, wanted.raw, timeout=self.timeouts.config)
            if answer.data[:1] != b"\x01":
                raise ConfigError(
                    f"the LMS2xx refused the configuration (units {self.units}, mode {self.mode}): "
                    f"reply F7 {answer.data[:8].hex(' ')}..."
                )
            wanted = p.ConfigBlock(answer.data[1:]) if len(answer.data) > 7 else wanted
        self.config = wanted
        if (wanted.mode, wanted.units) != (self.mode, self.units):
            raise ConfigError(
                f"the LMS2xx kept units {wanted.units} / mode {wanted.mode} instead of "
                f"{self.units} / {self.mode}"
            )

    # ---- request / reply ------------------------------------------------------------------------
    def _request(
        self, command: int, *data: int | bytes, expect: int | None = None, timeout: float | None = None
    ) -> Telegram:
        """Send a request and return the reply telegram with code ``expect`` (default command | 0x80)."""
        expect = p.reply_code(command) if expect is None else expect
        frame = request(command, *data)
        self._flush()
        naks = self._framer.counters.naks
        self._ser.write(frame)
        what = f"reply 0x{expect:02X} to {frame[4:-2].hex(' ')}"
        try:
            return self._wait_for(expect, self.timeouts.reply if timeout is None else timeout, what, naks)
        except ProtocolError:
            if self._framer.counters.naks == naks:
                raise
        # One NAK may be line noise: send once more.
        log.warning("LMS2xx on %s NAKed %s; sending it again", self.port, frame.hex(" "))
        self._flush()
        naks = self._framer.counters.naks
        self._ser.write(frame)
        return self._wait_for(expect, self.timeouts.reply if timeout is None else timeout, what, naks)

    def _wait_for(self, code: int, timeout: float, what: str, naks: int | None = None) -> Telegram:
        deadline = time.monotonic() + timeout
        heard = 0
        while time.monotonic() < deadline:
            self._check_closing()
            chunk = self._ser.read(self._ser.in_waiting or 1)
            heard += len(chunk)
            for tg in self._framer.feed(chunk):
                if tg.command == code:
                    return tg
                if tg.command == p.POWER_ON:
                    self._power_on_seen = True
                if tg.command == p.NOT_ACKNOWLEDGED:
                    raise ProtocolError(
                        f"expected {what}, got 0x92 'incorrect command' "
                        f"({tg.data.hex(' ')}); the device type may not support it"
                    )
            if naks is not None and self._framer.counters.naks > naks:
                raise ProtocolError(
                    f"expected {what}, got NAK (0x15): the LMS2xx received a corrupted telegram; "
                    f"check the cable and the baud ({self.baudrate})"
                )
        raise LinkLost(
            f"expected {what} within {timeout:g} s at {self.baudrate} baud on {self.port}, "
            f"got {heard} bytes and no such telegram; {CHECKS}"
        )

    def _flush(self) -> None:
        self._ser.reset_input_buffer()
        self._framer.reset()

    def _check_closing(self) -> None:
        if self._closing.is_set():
            raise _Closing

    def _sleep(self, seconds: float) -> None:
        if self._closing.wait(seconds):
            raise _Closing

    # ---- streaming ------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._closing.is_set():
                if self.link_state != "up":
                    if not self.recover:
                        self.last_error = LinkLost(
                            f"link to the LMS2xx on {self.port} lost and recover=False"
                        )
                        self._set_link("down", "not recovering (recover=False)")
                        return
                    self._recover()
                    continue
                try:
                    self._pump()
                except (serial.SerialException, OSError) as exc:
                    self._lost(f"serial error: {exc}")
        except _Closing:
            pass
        except Exception:  # a bug must not leave read() waiting forever
            log.exception("LMS2xx reader thread on %s failed", self.port)
            self.last_error = LinkLost("the reader thread failed; see the log")
            self._set_link("down", "reader thread failed")

    def _pump(self) -> None:
        chunk = self._ser.read(self._ser.in_waiting or 1)
        now = time.monotonic()
        # A telegram is sent in one piece: after a silence a pending partial frame is dead.
        found = self._framer.feed_positions(chunk) if chunk else [(tg, 0) for tg in self._framer.flush()]
        baud = self.baudrate
        for tg, after in found:
            if tg.command == p.VALUES:
                # The first ray: the telegram's first byte left the device after the whole sweep.
                t = now - transmit_time(after + tg.size, baud) - self._sweep
                if t <= self._last_stamp:
                    # Read-time jitter (a late read makes the next telegram look early): the stamps
                    # must still increase, as the mapper interpolates odometry between them.
                    self._stats["stamps_corrected"] += 1
                    t = self._last_stamp + 1e-6
                self._last_stamp = t
                self._deliver(tg, t)
            elif tg.command == p.POWER_ON:
                self._power_on_seen = True
                self._lost("the LMS2xx sent a power-on telegram (0x90): it rebooted")
                return
        silent = now - self._last_scan
        if silent > self.expected_period + self.timeouts.scan_margin:
            self._lost(f"no scan for {silent:.2f} s (expected every {self.expected_period * 1000:.0f} ms)")

    def _deliver(self, tg: Telegram, t: float) -> None:
        try:
            scan = decode_b0(tg, mode=self.mode, fov_deg=self.fov, t=t)
        except ValueError as exc:
            self._stats["bad_scans"] += 1
            log.debug("LMS2xx on %s: undecodable 0xB0: %s", self.port, exc)
            return
        self._stats["scans"] += 1
        self._last_scan = time.monotonic()
        with self._cond:
            self._scans.append(scan)
            self._cond.notify_all()
        for cb in self._scan_callbacks:
            try:
                cb(scan)
            except Exception:
                log.exception("LMS2xx scan callback %r failed", cb)

    def _lost(self, reason: str) -> None:
        self._stats["link_lost"] += 1
        log.warning("LMS2xx on %s: link lost: %s; restarting it", self.port, reason)
        self._set_link("lost", reason)

    def _recover(self) -> None:
        session_baud = self.target_baud
        try:
            self._startup(time.monotonic() + self.timeouts.recover)
        except (LaserError, serial.SerialException, OSError) as exc:
            self.last_error = exc
            log.warning("LMS2xx on %s: recovery failed (%s); trying again", self.port, exc)
            self._set_link("lost", str(exc))
            return
        if self._power_on_seen or self.detected_baud != session_baud:
            self._stats["reboots"] += 1
        self._stats["recoveries"] += 1
        log.warning("LMS2xx on %s recovered (found at %d baud)", self.port, self.detected_baud)

    def _set_link(self, state: str, reason: str) -> None:
        with self._cond:
            self.link_state = state
            self._cond.notify_all()
        event = LinkEvent(time.monotonic(), state, reason)
        log.info("LMS2xx on %s: link %s (%s)", self.port, state, reason)
        for cb in self._link_callbacks:
            try:
                cb(event)
            except Exception:
                log.exception("LMS2xx link callback %r failed", cb)
