"""A SICK LMS2xx on the master side of a pty (device side; spec lms2xx.md §2).

Answers the start-up sequences of ARIA, Player and sicktoolbox (ACK byte, reply telegram, status
0x10), NAKs telegrams with a bad CRC, switches baud (the reply goes out at the old rate) and
streams 0xB0 telegrams in continuous mode at the rate the real device reaches at its baud and
resolution. The codec is the one the reader uses (:mod:`laser.telegram`, :mod:`laser.values`).

A pty moves bytes at memory speed whatever its termios say, so the emulator compares the speed
the host set on the pty (:func:`serialport.ptys.line_speed`) with its own: when they differ, the host's
bytes are dropped as unintelligible and the device's output reaches the host as garbage, as on a
real line. That is what makes baud detection and reboot recovery testable.
"""

from __future__ import annotations

import logging
import os
import random
import select
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import ClassVar

import numpy as np

from laser import protocol as p
from laser.sources import RangeSource, constant
from laser.telegram import ACK, NAK, REPLY_BIT, FrameReader, Telegram, reply
from laser.timing import b0_size, mirror_period, scan_period, sweep_time, transmit_time
from laser.values import encode_b0, make_scan, scan_angles
from serialport.device import DeviceThread
from serialport.ptys import line_speed

log = logging.getLogger(__name__)

_POLL_S = 0.02  # longest sleep of the device loop: bounds stop() and power_cycle() latency


class LMS2xxEmulator(DeviceThread):
    """An LMS200 behind the pty master ``fd`` (the caller owns and closes the fd).

    ``ranges(t, angles_rad) -> metres`` supplies each scan (:mod:`laser.sources`). ``baud`` is the
    rate the device listens at when started (it powers on at 9600). ``fov``/``resolution`` (degrees)
    and ``units``/``mode`` are the initial variant and configuration, as kept in the device's EEPROM
    across power cycles. ``rate_limit=False`` streams at the mirror rate (75 Hz / interlacing) even
    where the baud would not allow it, for fast tests. ``boot_time`` is the seconds from reset or
    power-on to the 0x90 telegram (a real LMS needs ~30 s). ``garbage`` makes output at a baud the
    host is not listening at arrive as random bytes instead of nothing.
    """

    thread_name = "lms2xx-emulator"

    def __init__(
        self,
        fd: int,
        ranges: RangeSource | None = None,
        *,
        baud: int = p.POWER_ON_BAUD,
        fov: int = 180,
        resolution: float = 1.0,
        units: str = "mm",
        mode: int = 0,
        rate_limit: bool = True,
        boot_time: float = 0.2,
        garbage: bool = True,
        type_string: str = "LMS200;30106",
        version: str = "V02.10",
        address: int = 0,
        seed: int = 0,
    ) -> None:
        if baud not in p.BAUD_MODES:
            raise ValueError(f"an LMS2xx runs at {sorted(p.BAUD_MODES)} baud, not {baud}")
        super().__init__(fd)
        self.ranges = ranges or constant(2.0)
        self.rate_limit = rate_limit
        self.boot_time = boot_time
        self.garbage = garbage
        self.type_string = type_string
        self.version = version
        self.address = address
        self.baud = baud
        self.fov = fov
        self.resolution_cdeg = round(resolution * 100)
        self.config = p.ConfigBlock.default().with_settings(mode=mode, units=units)
        self.operating_mode = p.ON_REQUEST
        self.installation = False
        self.streaming = False
        self.counters: dict = {
            "telegrams": Counter(),
            "naks_sent": 0,
            "acks_sent": 0,
            "bytes_dropped": 0,
            "garbage_sent": 0,
            "bytes_lost": 0,
            "scans_sent": 0,
            "power_ons": 0,
        }
        self._framer = FrameReader()
        self._rng = random.Random(seed)
        self._lock = threading.RLock()
        self._booting_until: float | None = None
        self._new_baud: int | None = None
        self._next_scan = 0.0
        self._noise: list[bytes] = []

    # ---- test hooks ------------------------------------------------------------------------------
    def power_cycle(self, off_time: float | None = None) -> None:
        """Cut the power: silent for ``off_time`` (default ``boot_time``) s, then up at 9600 baud in
        mode 0x25 and sends the 0x90 power-on telegram. Variant and configuration survive (EEPROM)."""
        with self._lock:
            self._boot(self.boot_time if off_time is None else off_time)

    def inject(self, noise: bytes) -> None:
        """Write ``noise`` between two telegrams (line noise, a glitch) as soon as the device is idle."""
        with self._lock:
            self._noise.append(bytes(noise))

    @property
    def resolution(self) -> float:
        """Current angular resolution in degrees."""
        return self.resolution_cdeg / 100.0

    @property
    def count(self) -> int:
        """Values per scan of the current variant (181 at 180 deg / 1 deg)."""
        return round(self.fov * 100 / self.resolution_cdeg) + 1

    # ---- device loop -----------------------------------------------------------------------------
    def _run(self) -> None:
        poller = select.poll()
        poller.register(self.fd, select.POLLIN)
        while not self._stop.is_set():
            try:
                events = poller.poll(self._sleep() * 1000)
            except InterruptedError:
                continue
            if events:
                try:
                    data = os.read(self.fd, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:  # EIO: no host side open; a device keeps running
                    time.sleep(_POLL_S)
                    data = b""
                if data:
                    with self._lock:
                        self._receive(data)
            with self._lock:
                self._tick(time.monotonic())

    def _sleep(self) -> float:
        with self._lock:
            if self._noise:
                return 0.0
            if self.streaming and self._booting_until is None:
                return min(_POLL_S, max(0.0, self._next_scan - time.monotonic()))
        return _POLL_S

    def _tick(self, now: float) -> None:
        if self._booting_until is not None:
            if now < self._booting_until:
                return
            self._booting_until = None
            self.counters["power_ons"] += 1
            log.info("emulated LMS powered on at %d baud", self.baud)
            self._send(reply(p.POWER_ON, f"{self.type_string};{self.version} ".encode("ascii")))
        while self._noise:
            self._write(self._noise.pop(0))
        if self.streaming and now >= self._next_scan:
            self._send(self._scan_telegram(now))
            self.counters["scans_sent"] += 1
            # Keep the cadence, but never try to catch up a backlog a real device would not have.
            self._next_scan = max(self._next_scan + self._period(), now)

    def _period(self) -> float:
        res = self.resolution
        return scan_period(self.count, res, self.baud) if self.rate_limit else mirror_period(res)

    def _scan_telegram(self, now: float) -> bytes:
        """The 0xB0 telegram written at host time ``now`` (s). A real LMS sends a scan once its sweep
        is done, and its last byte arrives a transmission time later; this one arrives at once (a
        pty), so its sweep began ``sweep_time + transmit_time`` before ``now``: the range source is
        asked for that instant, the first ray's, as the reader dates it (:mod:`laser.timing`)."""
        swept = now - sweep_time(self.fov, self.resolution) - transmit_time(b0_size(self.count), self.baud)
        metres = np.asarray(
            self.ranges(swept, scan_angles(self.count, self.fov, self.resolution)), dtype=np.float64
        )
        scan = make_scan(
            metres,
            fov_deg=self.fov,
            resolution_deg=self.resolution,
            units=self.config.units,
            mode=self.config.mode,
        )
        return encode_b0(scan)

    def _boot(self, seconds: float) -> None:
        self.streaming = False
        self.installation = False
        self.operating_mode = p.ON_REQUEST
        self.baud = p.POWER_ON_BAUD
        self._booting_until = time.monotonic() + seconds
        self._framer.reset()

    # ---- input -----------------------------------------------------------------------------------
    def _receive(self, data: bytes) -> None:
        if self._booting_until is not None or line_speed(self.fd) != self.baud:
            self.counters["bytes_dropped"] += len(data)
            return
        bad_before = self._framer.counters.bad_crc
        telegrams = self._framer.feed(data)
        for _ in range(self._framer.counters.bad_crc - bad_before):
            self._write(bytes((NAK,)))
            self.counters["naks_sent"] += 1
        for tg in telegrams:
            if tg.is_reply or tg.address != self.address:
                continue  # another device's traffic on a multi-drop line
            self.counters["telegrams"][tg.command] += 1
            self._handle(tg)

    def _handle(self, tg: Telegram) -> None:
        handler: Callable[[Telegram], bytes | None] | None = self._HANDLERS.get(tg.command)
        answer = handler(self, tg) if handler else None
        self._ack()
        self._send(answer if answer is not None else self._reply(p.NOT_ACKNOWLEDGED, bytes((tg.command,))))
        if tg.command == p.RESET:
            self._boot(self.boot_time)
        elif self._new_baud:
            # Only now: the reply above still went out at the old rate.
            self.baud, self._new_baud = self._new_baud, None
            log.info("emulated LMS now at %d baud", self.baud)

    def _reply(self, code: int, data: bytes = b"") -> bytes:
        return reply(code, data, address=self.address | REPLY_BIT)

    def _on_reset(self, tg: Telegram) -> bytes:
        return self._reply(p.RESET_CONFIRM)

    def _on_switch_mode(self, tg: Telegram) -> bytes | None:
        if not tg.data:
            return None
        mode = tg.data[0]
        ok = p.MODE_OK
        if mode == p.INSTALLATION:
            password = tg.data[1:9]
            ok = p.MODE_OK if password == p.password_for(self.type_string) else p.MODE_REFUSED
            self.installation = ok == p.MODE_OK
        elif mode == p.CONTINUOUS:
            self.streaming, self.installation = True, False
            self._next_scan = time.monotonic() + self._period()
        elif mode == p.ON_REQUEST:
            self.streaming, self.installation = False, False
        elif mode in p.BAUD_CODES:
            self._new_baud = p.BAUD_CODES[mode]
        else:
            ok = p.MODE_REFUSED  # diagnostic, field and partial-scan modes are not emulated
        if ok == p.MODE_OK and mode in (p.CONTINUOUS, p.ON_REQUEST, p.INSTALLATION):
            self.operating_mode = mode
        return self._reply(p.SWITCH_MODE | 0x80, bytes((ok,)))

    def _on_request_values(self, tg: Telegram) -> bytes:
        return self._scan_telegram(time.monotonic())

    def _on_request_status(self, tg: Telegram) -> bytes:
        return self._reply(
            p.REQUEST_STATUS | 0x80, p.status_data(self.version, self.fov, self.resolution_cdeg)
        )

    def _on_request_type(self, tg: Telegram) -> bytes:
        return self._reply(p.REQUEST_TYPE | 0x80, self.type_string.encode("ascii"))

    def _on_switch_variant(self, tg: Telegram) -> bytes | None:
        if len(tg.data) < 4:
            return None
        req = p.VariantReply.parse(b"\0" + tg.data[:4])
        # 0 means "keep": AriaCoda sends resolution 0 (spec §2.9); never divide by it.
        fov = req.fov or self.fov
        res = req.resolution_cdeg or self.resolution_cdeg
        accepted = res in p.VARIANTS.get(fov, ())
        if accepted:
            self.fov, self.resolution_cdeg = fov, res
        answer = p.VariantReply(accepted, self.fov, self.resolution_cdeg)
        return self._reply(p.SWITCH_VARIANT | 0x80, answer.encode())

    def _on_request_config(self, tg: Telegram) -> bytes:
        return self._reply(p.REQUEST_CONFIG | 0x80, self.config.raw)

    def _on_configure(self, tg: Telegram) -> bytes | None:
        if len(tg.data) < 7:
            return None
        new = self.config.overlay(tg.data)
        ok = self.installation and new.is_valid()
        if ok:
            self.config = new
        return self._reply(p.CONFIGURE | 0x80, bytes((int(ok),)) + self.config.raw)

    _HANDLERS: ClassVar[dict[int, Callable]] = {
        p.RESET: _on_reset,
        p.SWITCH_MODE: _on_switch_mode,
        p.REQUEST_VALUES: _on_request_values,
        p.REQUEST_STATUS: _on_request_status,
        p.REQUEST_TYPE: _on_request_type,
        p.SWITCH_VARIANT: _on_switch_variant,
        p.REQUEST_CONFIG: _on_request_config,
        p.CONFIGURE: _on_configure,
    }

    # ---- output ----------------------------------------------------------------------------------
    def _ack(self) -> None:
        self._send(bytes((ACK,)))
        self.counters["acks_sent"] += 1

    def _send(self, data: bytes) -> None:
        """Transmit at the device's baud: garbage (or nothing) if the host listens at another."""
        if line_speed(self.fd) == self.baud:
            self._write(data)
        elif self.garbage:
            self.counters["garbage_sent"] += len(data)
            self._write(self._rng.randbytes(len(data)))

    def _write(self, data: bytes) -> None:
        self.counters["bytes_lost"] += self._transmit(data)
