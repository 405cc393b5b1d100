"""Hardware bring-up helpers behind ``asrmap probe laser`` and ``asrmap emulate laser``."""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from laser.emulator import LMS2xxEmulator
from laser.reader import LMS2xx, Timeouts
from laser.sources import RangeSource, room
from laser.values import LaserScan
from serialport.ptys import open_pty


@dataclass(frozen=True)
class ProbeReport:
    """What one start-up and ``duration`` seconds of scanning showed. Ranges in metres."""

    port: str
    detected_baud: int
    baudrate: int
    device_type: str
    fov_deg: int
    resolution_deg: float
    units: str
    mode: int
    config_hex: str
    duration: float
    scans: int
    count: int
    max_range: float
    ranges_m: tuple[float, float, float] = (float("nan"),) * 3  # min, median, max over valid beams
    no_return: int = 0
    counters: dict = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        return self.scans / self.duration if self.duration > 0 else 0.0

    def lines(self) -> list[str]:
        """The report as the lines ``asrmap probe laser`` prints."""
        lo, med, hi = self.ranges_m
        return [
            f"device   {self.device_type} on {self.port} "
            f"(found at {self.detected_baud} baud, now {self.baudrate})",
            f"variant  {self.fov_deg} deg at {self.resolution_deg} deg ({self.count} values per scan)",
            f"config   units {self.units}, measuring mode {self.mode} (max range {self.max_range:.3f} m); "
            f"block {self.config_hex}",
            f"scans    {self.scans} in {self.duration:.1f} s = {self.rate_hz:.1f} Hz",
            f"ranges   min {lo:.3f} m, median {med:.3f} m, max {hi:.3f} m; "
            f"{self.no_return} no-return readings",
            "counters " + ", ".join(f"{k} {v}" for k, v in self.counters.items()),
        ]


def probe(
    port: str,
    baudrate: int = 38400,
    *,
    duration: float = 2.0,
    resolution: float = 1.0,
    fov: int = 180,
    units: str = "mm",
    mode: int = 5,
    timeouts: Timeouts | None = None,
) -> ProbeReport:
    """Run the full start-up on ``port``, collect ``duration`` s of scans, return what was seen.

    Raises :class:`~laser.errors.LinkLost` (with what to check) if the device does not answer.
    """
    scans: list[LaserScan] = []
    with LMS2xx(
        port,
        baudrate,
        resolution=resolution,
        fov=fov,
        units=units,
        mode=mode,
        timeouts=timeouts,
        recover=False,
    ) as lms:
        start = time.monotonic()
        while (left := start + duration - time.monotonic()) > 0:
            scan = lms.read(timeout=left)
            if scan is not None:
                scans.append(scan)
        elapsed = time.monotonic() - start
        report = dict(
            port=port,
            detected_baud=lms.detected_baud or 0,
            baudrate=lms.baudrate,
            device_type=lms.device_type,
            fov_deg=fov,
            resolution_deg=lms.resolution,
            units=units,
            mode=mode,
            config_hex=lms.config.raw.hex(" ") if lms.config else "",
            duration=elapsed,
            scans=len(scans),
            count=lms.count,
            counters=lms.counters,
        )
    if not scans:
        return ProbeReport(max_range=float("nan"), **report)
    ranges = np.concatenate([s.ranges for s in scans])
    missing = np.concatenate([s.no_return for s in scans])
    valid = ranges[~missing]
    stats = (
        (float(valid.min()), float(np.median(valid)), float(valid.max()))
        if len(valid)
        else (float("nan"),) * 3
    )
    return ProbeReport(max_range=scans[0].max_range, ranges_m=stats, no_return=int(missing.sum()), **report)


@contextmanager
def emulated_laser(ranges: RangeSource | None = None, *, baud: int = 9600, rate_limit: bool = True, **kwargs):
    """A pty with an :class:`LMS2xxEmulator` on its master (a fixed synthetic room unless ``ranges``
    is given); yields ``(pty, emulator)``, ``pty.path`` being the device to open."""
    with (
        open_pty() as pair,
        LMS2xxEmulator(pair.master, ranges or room(), baud=baud, rate_limit=rate_limit, **kwargs) as emu,
    ):
        yield pair, emu
