"""Simulated LMS200: one vectorised ray-cast scan (with range noise) in the built-in worlds.

The simulator casts a scan per laser period; at ``--fast 10`` and 75 Hz that is 750 scans per
wall second, so a scan must cost well under a millisecond. Poses walk along a line inside each
world's free space so the beams see varied geometry.
"""

from __future__ import annotations

import time

import numpy as np

from service.sim.raycast import RayCaster
from service.sim.world import load_world

NAME = "raycast"
HELP = "simulated LMS200 scans (181 and 361 beams) ray-cast per second in the built-in worlds"


def run(args) -> dict:
    n = 100 if getattr(args, "quick", False) else 1000
    figures = {}
    for world_name in ("lab", "office", "aliasing"):
        world = load_world(world_name)
        rc = RayCaster(world)
        x0, y0, th0 = world.start
        for beams in (181, 361):
            angles = np.radians(np.linspace(-90.0, 90.0, beams))
            rc.scan(world.start, angles)  # warm-up
            times = np.empty(n)
            for i in range(n):
                pose = (x0 + 0.002 * i, y0, th0 + 0.01 * i)
                t0 = time.perf_counter()
                rc.scan(pose, angles)
                times[i] = time.perf_counter() - t0
            ms = times * 1e3
            med, p99 = float(np.median(ms)), float(np.percentile(ms, 99))
            print(f"{world_name:9s} {beams} beams: median {med:.3f} ms, p99 {p99:.3f} ms, "
                  f"{1e3 / med:,.0f} scans/s")
            figures[f"{world_name}/{beams}"] = {"median_ms": med, "p99_ms": p99}
    return figures
