"""``asrmap bench mapper``: per-scan time of the mapper core over the 5505 Intel raw scans.

The whole core per scan (points, localisation, and on viewpoint scans line extraction, exits, the
view polygon and the ASR union; and whatever else ``Mapper.add_scan`` runs, e.g. the cycle check),
timed around ``Mapper.add_scan`` on one core; the log is parsed before timing. The mapper runs
pipelined as in ``asrmap replay`` (``defer_views=True``: a viewpoint's work spread over it and the
next one or two scans, the same map); the figures with each view's work in its own scan
(as the live service runs) follow, and those of the core alone (cycle closing off, so no
surface alignment: the scope of the mapper-core issue). Prints median, p99
and max of the wall clock and of this thread's CPU time (which other processes on a busy machine
do not inflate), scans/s and the real-time factor (log duration / compute time), then each stage's
median and p99 over the scans that ran it (``Mapper.timing``, wall clock), and the cost of
extraction + exits + view on *every* scan (as if each scan were a viewpoint). ``--runs N`` replays
the pipelined and core-alone cases N times and prints each run's median and p99 and the median of
the runs' p99: this machine's timings vary by tens of per cent between identical runs.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from mapper.exits import find_covers
from mapper.lines import extract_surfaces, scan_points
from mapper.mapper import Mapper
from mapper.params import MapperParams
from mapper.types import Scan
from mapper.view import build_view
from service.carmen import mapper_inputs
from service.datasets import log_path

NAME = "mapper"
HELP = "mapper core per scan (extraction, exits, localisation, ASR update) over the 5505 Intel raw scans"
LOG = "intel-raw-first5505.clf.gz"


def _stats(ms: np.ndarray) -> str:
    return f"median {np.median(ms):.3f} ms  p99 {np.percentile(ms, 99):.3f} ms  max {ms.max():.3f} ms"


def run(args=None) -> dict:
    items = list(mapper_inputs(log_path(LOG)))
    if getattr(args, "quick", False):
        items = items[:1600]
    params = MapperParams(laser_x=0.0, laser_y=0.0)  # the log's ranges are relative to the robot centre
    scans = [i for i in items if isinstance(i, Scan)]
    m, per_scan, cpu, stages = _replay(items, params, defer_views=True)
    ms = np.asarray(per_scan) * 1e3
    duration = scans[-1].t - scans[0].t
    total = ms.sum() / 1e3
    out = {
        "scans": len(ms),
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "scans_per_s": len(ms) / total,
        "realtime_factor": duration / total,
        "asrs": len(m.asrs),
    }
    cms = np.asarray(cpu) * 1e3
    out["cpu_median_ms"], out["cpu_p99_ms"] = float(np.median(cms)), float(np.percentile(cms, 99))
    print(f"whole core, pipelined as in replay, {len(ms)} scans ({len(m.asrs)} ASRs): {_stats(ms)}")
    print(f"  CPU time of this thread (unaffected by other processes): {_stats(cms)}")
    rtf = out["realtime_factor"]
    print(f"  {out['scans_per_s']:.0f} scans/s; log {duration:.1f} s in {total:.2f} s: {rtf:.0f}x real time")
    for k, v in stages.items():
        s = np.asarray(v) * 1e3
        out[f"{k}_median_ms"] = float(np.median(s))
        out[f"{k}_p99_ms"] = float(np.percentile(s, 99))
        out[f"{k}_total_s"] = float(s.sum() / 1e3)
        print(f"  stage {k:9s} ({len(s):4d} scans): {_stats(s)}  total {s.sum() / 1e3:.2f} s")
    # The core alone (the mapper-core issue's scope: no cycle check, so no surface alignment)
    core = dataclasses.replace(params, cycles=dataclasses.replace(params.cycles, enabled=False))
    mc, alone, _, _ = _replay(items, core, defer_views=True)
    alone_ms = np.asarray(alone) * 1e3
    out["core_median_ms"], out["core_p99_ms"] = float(np.median(alone_ms)), float(np.percentile(alone_ms, 99))
    print(f"  the core alone, cycle closing off ({len(mc.asrs)} ASRs): {_stats(alone_ms)}")
    runs = int(getattr(args, "runs", 1) or 1)
    if runs > 1:  # the same replays again: this machine's timings vary between runs
        cases = (("pipelined", "pipelined", params, ms), ("core alone", "core", core, alone_ms))
        for label, key, pp, first in cases:
            more = [np.asarray(_replay(items, pp, defer_views=True)[1]) * 1e3 for _ in range(runs - 1)]
            per = [first, *more]
            med, p99 = [float(np.median(r)) for r in per], [float(np.percentile(r, 99)) for r in per]
            out[f"{key}_runs_p99_ms"] = p99
            print(f"  {label}, {runs} runs: median {' '.join(f'{x:.3f}' for x in med)} ms; "
                  f"p99 {' '.join(f'{x:.2f}' for x in p99)} ms (median of runs {np.median(p99):.2f})")
    _, now, now_cpu, _ = _replay(items, params, defer_views=False)
    now_ms, now_cpu = np.asarray(now) * 1e3, np.asarray(now_cpu) * 1e3
    out["immediate_median_ms"] = float(np.median(now_ms))
    out["immediate_p99_ms"] = float(np.percentile(now_ms, 99))
    out["immediate_max_ms"] = float(now_ms.max())
    print(f"  each view's work in its own scan (defer_views=False, as the live service): {_stats(now_ms)}")
    print(f"    CPU time: {_stats(now_cpu)}; {len(now_ms) / (now_ms.sum() / 1e3):.0f} scans/s")
    every = []
    for sc in scans[:: 5 if getattr(args, "quick", False) else 1]:
        tic = time.perf_counter()
        surf = extract_surfaces(scan_points(sc, params), params)
        build_view(surf, params, find_covers(surf, params))
        every.append(time.perf_counter() - tic)
    e = np.asarray(every) * 1e3
    out["view_every_scan_median_ms"] = float(np.median(e))
    print(f"  extraction+exits+view on every scan: {_stats(e)}")
    return out


def _replay(items, params: MapperParams, defer_views: bool):
    """Feed the readings to a new mapper; per-scan wall and thread CPU times (s), stage timings."""
    m = Mapper(params, defer_views=defer_views)
    per_scan, cpu, stages = [], [], {}
    for item in items:
        if isinstance(item, Scan):
            tic, cpu0 = time.perf_counter(), time.thread_time()
            m.add_scan(item)
            per_scan.append(time.perf_counter() - tic)
            cpu.append(time.thread_time() - cpu0)
            for k, v in m.timing.items():
                stages.setdefault(k, []).append(v)
        else:
            m.add_odometry(item)
    tic = time.perf_counter()
    m.flush()  # the last view's remaining stages, counted with the last scan
    per_scan[-1] += time.perf_counter() - tic
    return m, per_scan, cpu, stages


if __name__ == "__main__":
    run()
