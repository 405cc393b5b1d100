"""Compile the mapper's kernels (:mod:`mapper.jit`) before the first real scan.

A kernel compiles on its first call in a process, or loads from numba's disk cache: about 10 s
for all of them the first time on a machine, about 0.3 s once cached. Paid inside a scan, that
is a stall of the live service (its watchdog is 10 s) or a skewed replay throughput.
:func:`warm_up` pays it up front by mapping a short synthetic run: a rectangular room with a
doorway, seen from a robot that turns in place and drives, so that every stage and kernel runs
with the array types real scans give it; and two searches that run never reaches, on the room's
walls: the cycle check's surface alignment (it revisits nothing) and the search for exits passed
and dropped (it crosses no doorway). ``tests/test_jit_cache.py`` replays Intel raw after it and
fails if any kernel compiles then.
"""

from __future__ import annotations

import math

import numpy as np

from mapper.asr_builder import _lying_along
from mapper.cycles import align_points
from mapper.params import MapperParams
from mapper.types import Odometry, Scan

#: The room (m, world frame): walls as segments, a 0.9 m doorway in the east wall.
_WALLS = np.array([
    [[-3.0, -2.0], [3.0, -2.0]], [[3.0, -2.0], [3.0, -0.45]], [[3.0, 0.45], [3.0, 2.0]],
    [[3.0, 2.0], [-3.0, 2.0]], [[-3.0, 2.0], [-3.0, -2.0]],
    [[3.0, -0.45], [4.0, -0.45]], [[3.0, 0.45], [4.0, 0.45]],  # the doorway's passage
])


def _ranges(pose: tuple[float, float, float], beams: int, max_range: float) -> np.ndarray:
    """Ranges (m) of a 180° sweep from ``pose`` (world frame) to the room's walls."""
    a = pose[2] - math.pi / 2 + np.linspace(0.0, math.pi, beams)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    p0, p1 = _WALLS[:, 0], _WALLS[:, 1]
    e = p1 - p0
    w = p0 - np.array(pose[:2])
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den
    t = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf)
    return np.minimum(t.min(axis=1), max_range)


def warm_up(params: MapperParams | None = None) -> None:
    """Map a few seconds of a synthetic room with a new mapper (both pipelined and not), so that
    every kernel is compiled or loaded. The result is thrown away; nothing else changes."""
    from mapper.mapper import Mapper  # here: mapper.mapper imports this module

    params = params or MapperParams()
    beams, max_range = 181, 8.0
    for defer in (True, False):
        m = Mapper(params, defer_views=defer)
        t = 0.0
        # turn in place a full circle, then drive towards the doorway
        poses = [(0.0, 0.0, i * math.radians(6.0)) for i in range(61)]
        poses += [(0.05 * i, 0.0, 0.0) for i in range(1, 50)]
        for pose in poses:
            t += 0.1
            m.add_odometry(Odometry(t, *pose))
            r = _ranges(pose, beams, max_range)
            m.add_scan(Scan(t, r, -math.pi / 2, math.pi / (beams - 1), max_range))
        m.flush()
    _align_walls()
    _lying_along_walls()


def _align_walls() -> None:
    """:func:`mapper.cycles.align_points` of the room's walls, 11 points along each with their unit
    normals (world frame), onto themselves."""
    a, b = _WALLS[:, 0], _WALLS[:, 1]
    f = np.linspace(0.0, 1.0, 11)
    pts = (a[:, None, :] + f[None, :, None] * (b - a)[:, None, :]).reshape(-1, 2)
    d = (b - a) / np.hypot(*(b - a).T)[:, None]
    normals = np.repeat(np.stack([-d[:, 1], d[:, 0]], axis=1), len(f), axis=0)
    align_points(pts, pts, normals, 0.1, p_normals=normals)


def _lying_along_walls() -> None:
    """:func:`mapper.asr_builder._lying_along` of the room's walls against themselves: the search
    for passed exits and dropped exit segments, which the synthetic room's views never need (its
    doorway is not crossed) and a real run does within its first minutes (Intel raw)."""
    _lying_along(_WALLS, _WALLS, 0.1)
