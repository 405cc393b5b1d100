"""Vectorised ray casting of line segments: synthetic scans with exact answers for the mapper tests."""

from __future__ import annotations

import math

import numpy as np

from mapper.types import Scan


def box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The four walls of an axis-aligned rectangle as segments (m)."""
    return [((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))]


def cast(
    walls,
    pose=(0.0, 0.0, 0.0),
    n: int = 181,
    fov: float = math.pi,
    max_range: float = 50.0,
    no_return: float = 81.91,
    t: float = 0.0,
    laser=(0.0, 0.0),
) -> Scan:
    """A scan from the laser at ``laser`` (robot frame) of the robot at ``pose`` (world frame).

    ``walls``: segments ((x, y), (x, y)) in the world frame (m). Beams that hit nothing within
    ``max_range`` read ``no_return``. Beam i at -fov/2 + i * fov/(n-1) (rad, laser frame).
    """
    w = np.asarray(walls, dtype=float).reshape(-1, 2, 2)
    x, y, th = pose
    ox = x + math.cos(th) * laser[0] - math.sin(th) * laser[1]
    oy = y + math.sin(th) * laser[0] + math.cos(th) * laser[1]
    inc = fov / (n - 1)
    ang = th - fov / 2 + inc * np.arange(n)
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)[:, None, :]  # (n, 1, 2)
    a = w[None, :, 0, :] - np.array([ox, oy])  # (1, m, 2)
    e = (w[:, 1] - w[:, 0])[None]  # (1, m, 2)
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        tr = (a[..., 0] * e[..., 1] - a[..., 1] * e[..., 0]) / den
        u = (a[..., 0] * d[..., 1] - a[..., 1] * d[..., 0]) / den
    hit = (np.abs(den) > 1e-12) & (tr > 1e-9) & (u >= -1e-9) & (u <= 1 + 1e-9)
    r = np.where(hit, tr, np.inf).min(axis=1)
    r = np.where(r <= max_range, r, no_return)
    return Scan(t, r.astype(np.float32), -fov / 2, inc, max_range)
