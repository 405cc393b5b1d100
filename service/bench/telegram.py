"""LMS2xx 0xB0 telegrams: incremental framing + CRC + decoding into LaserScan, on one core.

Ranges come from the real MIT CSAIL log (361 beams, 0.5 deg): each FLASER sweep is encoded as the
device would send it (cm units, measuring mode 0), the telegrams are concatenated into one byte
stream and fed to :class:`laser.telegram.FrameReader` in 4 KiB chunks, as a serial port delivers them.
"""

from __future__ import annotations

import time

import numpy as np

from laser.telegram import FrameReader
from laser.values import decode_b0, encode_b0, make_scan
from service import carmen
from service.datasets import log_path

NAME = "telegram"
HELP = "LMS2xx 361-value 0xB0 telegrams decoded per second through the incremental reader (goal >= 20,000/s)"
LOG = "mit-csail.clf.gz"
CHUNK = 4096


def _telegrams(limit: int) -> list[bytes]:
    out = []
    for rec in carmen.read(log_path(LOG)):
        if isinstance(rec, carmen.LaserRecord) and len(rec.ranges) == 361:
            out.append(encode_b0(make_scan(rec.ranges, fov_deg=180, units="cm", mode=0)))
            if len(out) >= limit:
                break
    return out


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    frames = _telegrams(300 if quick else 2000)
    stream = b"".join(frames)
    repeats = 1 if quick else 5

    decoded = 0
    best = float("inf")
    for _ in range(repeats):
        reader = FrameReader()
        t0 = time.perf_counter()
        for i in range(0, len(stream), CHUNK):
            for tg in reader.feed(stream[i : i + CHUNK]):
                decode_b0(tg, mode=0, fov_deg=180)
                decoded += 1
        best = min(best, time.perf_counter() - t0)
    rate = len(frames) / best

    reader = FrameReader()
    lat = np.empty(len(frames))
    for i, frame in enumerate(frames):
        t0 = time.perf_counter_ns()
        for tg in reader.feed(frame):
            decode_b0(tg, mode=0, fov_deg=180)
        lat[i] = (time.perf_counter_ns() - t0) / 1000.0
    med, p99 = np.percentile(lat, [50, 99])
    mbytes = len(stream) / best / 1e6
    print(f"  {len(frames)} telegrams of {len(frames[0])} bytes from {LOG} ({decoded // repeats} decoded)")
    print(f"  throughput {rate:,.0f} telegrams/s ({mbytes:.1f} MB/s; goal >= 20,000/s)")
    print(f"  latency per telegram (feed + decode): median {med:.1f} us, p99 {p99:.1f} us")
    return {"telegrams_per_s": rate, "median_us": float(med), "p99_us": float(p99)}
