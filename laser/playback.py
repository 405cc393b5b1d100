"""An LMS2xx that plays back recorded scans (device side; spec lms2xx.md §2.4).

:class:`PlaybackLMS2xx` is the :class:`laser.emulator.LMS2xxEmulator` (same start-up sequences,
baud switching, configuration) whose continuous mode streams the scans of a recording instead of
a range source: each one as a 0xB0 telegram with the logged ranges in the units and measuring mode
the host configured (1 mm, 1 cm ...), readings at or beyond ``no_return`` (m) and non-finite ones
sent as the device's all-ones no-return code, and the beam count of the recording (a 180-beam
CARMEN sweep stays 180 values; the reader derives the beam spacing from the count and the FOV).

Timing: scan ``k`` (recorded at ``times[k]`` s) is due at host time ``to_wall(times[k])``; its
telegram is written one mirror sweep plus one transmission time (at the line's baud) after that,
because the reader dates a scan's first ray by the telegram's arrival minus both: the date it
computes is then the recorded one on the same clock. ``to_wall`` returns None until playback
starts (the device is silent).
With ``rate_limit`` (the default) telegrams never follow each other faster than the baud allows;
a scan is skipped (``counters["scans_skipped"]``) only when the line is two or more scans
behind, as a real device sends its newest scan when the line frees. ``rate_limit=False`` sends
every scan in order as soon as it is due, whatever the baud.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from laser.emulator import _POLL_S, LMS2xxEmulator
from laser.timing import b0_size, sweep_time, transmit_time
from laser.values import encode_b0, make_scan

#: ``to_wall(t_recorded) -> host time.monotonic() seconds``, or None while playback has not started.
ToWall = Callable[[float], "float | None"]


class PlaybackLMS2xx(LMS2xxEmulator):
    """An LMS2xx on the pty master ``fd`` streaming ``scans`` (metres, one row or sequence per
    scan, beam 0 on the right) recorded at ``times`` (s, non-decreasing order expected; later
    ones out of order are sent right after their predecessor), over ``fov`` degrees.
    ``kwargs`` go to :class:`~laser.emulator.LMS2xxEmulator` (``baud``, ``boot_time``...).
    """

    def __init__(self, fd: int, times: Sequence[float], scans: Sequence, to_wall: ToWall, *,
                 fov: int = 180, no_return: float = 50.0, rate_limit: bool = True, **kwargs) -> None:
        super().__init__(fd, fov=fov, rate_limit=rate_limit, **kwargs)
        if len(times) != len(scans):
            raise ValueError(f"{len(times)} times for {len(scans)} scans")
        self.times = np.asarray(times, dtype=np.float64)
        self.scans = scans
        self.to_wall = to_wall
        self.no_return = no_return
        self.next_index = 0
        self._line_free = 0.0
        self.counters.update(scans_skipped=0, playback_late_max=0.0)

    @property
    def finished(self) -> bool:
        """Every recorded scan has been sent or skipped."""
        return self.next_index >= len(self.times)

    def _tick(self, now: float) -> None:
        # The base class sends the power-on telegram and injected noise; streaming is ours.
        streaming, self.streaming = self.streaming, False
        try:
            super()._tick(now)
        finally:
            self.streaming = streaming
        if self.streaming and self._booting_until is None:
            self._play(now)

    def _sleep(self) -> float:
        with self._lock:
            if self._noise:
                return 0.0
            due = self._due(self.next_index) if self.streaming and not self.finished else None
        if due is None:
            return _POLL_S
        return min(_POLL_S, max(0.0, max(due, self._line_free) - time.monotonic()))

    def _tx(self, k: int) -> float:
        return transmit_time(b0_size(len(self.scans[k])), self.baud)

    def _due(self, k: int) -> float | None:
        """Host time at which scan ``k``'s telegram may be written (its last byte 'arrives')."""
        wall = self.to_wall(float(self.times[k]))
        return None if wall is None else wall + sweep_time(self.fov, self.resolution) + self._tx(k)

    def _play(self, now: float) -> None:
        k = self.next_index
        if k >= len(self.times) or now < self._line_free:
            return
        due = self._due(k)
        if due is None or now < due:
            return
        if self.rate_limit:
            # The newest scan due now: when the line is two or more scans behind, the device drops.
            j = k
            while j + 1 < len(self.times) and (d := self._due(j + 1)) is not None and d <= now:
                j += 1
            if j - k >= 2:
                self.counters["scans_skipped"] += j - k
                k, due = j, self._due(j)
        tg = self._telegram(k)
        self._send(tg)
        self.counters["scans_sent"] += 1
        self.counters["playback_late_max"] = max(self.counters["playback_late_max"], now - due)
        self.next_index = k + 1
        if self.rate_limit:
            self._line_free = now + transmit_time(len(tg), self.baud)

    def _telegram(self, k: int) -> bytes:
        r = np.asarray(self.scans[k], dtype=np.float64)
        # What the device reports as no return is its all-ones code, whatever the log wrote there.
        r = np.where(np.isfinite(r) & (r < self.no_return), r, np.inf)
        scan = make_scan(r, fov_deg=self.fov, units=self.config.units, mode=self.config.mode)
        return encode_b0(scan)

