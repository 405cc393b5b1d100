"""An ASR's unknown regions and free space, in the ASR's own frame (m): runs of ``unknown`` boundary
edges cut into regions to look at, the polygon shrunk by the robot's clearance, an exit's outward
normal."""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.ops import nearest_points

from mapper.types import ASR, Exit


def unknown_runs(asr: ASR) -> list[tuple[np.ndarray, float]]:
    """Maximal runs of consecutive ``unknown`` edges of the boundary: (points (K, 2), length m)."""
    b = np.asarray(asr.boundary, dtype=float)
    n = len(b)
    unk = np.array([e == "unknown" for e in asr.edges], dtype=bool)
    if n < 3 or not unk.any():
        return []
    if unk.all():
        pts = np.vstack([b, b[:1]])
        return [(pts, float(np.hypot(*np.diff(pts, axis=0).T).sum()))]
    # Start the walk just after a non-unknown edge so no run is split across the wrap-around.
    first = (int(np.flatnonzero(~unk)[0]) + 1) % n
    runs, cur = [], []
    for k in range(n):
        i = (first + k) % n
        if unk[i]:
            if not cur:
                cur.append(b[i])
            cur.append(b[(i + 1) % n])
        elif cur:
            runs.append(np.array(cur))
            cur = []
    if cur:
        runs.append(np.array(cur))
    return [(r, float(np.hypot(*np.diff(r, axis=0).T).sum())) for r in runs]


def _points_along(pts: np.ndarray, fractions: np.ndarray) -> list[tuple[float, float]]:
    """Points at the given fractions (0..1) of the length of the polyline ``pts`` (m)."""
    step = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(step)])
    if cum[-1] <= 0.0:
        return [(float(pts[0, 0]), float(pts[0, 1]))] * len(fractions)
    s = np.asarray(fractions) * cum[-1]
    k = np.clip(np.searchsorted(cum, s) - 1, 0, len(step) - 1)
    f = np.where(step[k] > 0, (s - cum[k]) / np.where(step[k] > 0, step[k], 1.0), 0.0)
    p = pts[k] + f[:, None] * (pts[k + 1] - pts[k])
    return [(float(x), float(y)) for x, y in p]


def unknown_regions(asr: ASR, min_length: float, piece: float) -> list[tuple[float, float]]:
    """Unknown regions of ``asr`` (ASR frame): each unknown run at least ``min_length`` m long, cut
    into pieces of at most ``piece`` m (a long run wraps round the unseen rear of a view, and its
    middle alone would say nothing about its ends); one point per piece, at the piece's middle."""
    out = []
    for pts, length in unknown_runs(asr):
        if length < min_length:
            continue
        k = max(1, math.ceil(length / piece))
        out += _points_along(pts, (np.arange(k) + 0.5) / k)
    return out


def free_space(asr: ASR, clearance: float) -> shapely.Geometry:
    """``asr``'s polygon shrunk by ``clearance`` (m, the ASR's frame): where the robot's centre may
    go."""
    poly = shapely.make_valid(asr.polygon)
    return poly.buffer(-clearance)


def inside_point(free: shapely.Geometry, near: tuple[float, float], fallback: tuple[float, float]):
    """The point of ``free`` nearest ``near`` (``fallback`` when there is no free space)."""
    if free.is_empty:
        return fallback
    p = shapely.Point(near)
    if free.covers(p):
        return near
    q = nearest_points(free, p)[0]
    return (float(q.x), float(q.y))


def shape_key(asr: ASR) -> bytes:
    """The boundary's coordinates as bytes: a cache key that changes exactly when the boundary does.

    Not ``id(asr.boundary)``: a relabelled ASR gets a new boundary array, and a new array may take
    the address of a freed one, so the caches keyed by it returned answers about an older boundary
    (whether they did depended on the process's memory layout: the simulated runs changed with the
    bytes of a module they never import)."""
    return np.asarray(asr.boundary, dtype=float).tobytes()


def exit_normal(asr: ASR, ex: Exit) -> np.ndarray:
    """Unit normal of the exit pointing out of the ASR (ASR frame)."""
    return outward(asr, np.asarray(ex.a, float), np.asarray(ex.b, float))


def outward(asr: ASR, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unit normal of the chord ``a`` -> ``b`` pointing out of the ASR (ASR frame)."""
    d = b - a
    n = np.array([d[1], -d[0]]) / max(float(np.hypot(*d)), 1e-9)
    mid = (a + b) / 2.0
    poly = asr.polygon
    probe = 0.05
    inside_plus = poly.contains(shapely.Point(mid + probe * n))
    inside_minus = poly.contains(shapely.Point(mid - probe * n))
    if inside_plus and not inside_minus:
        return -n
    if inside_minus and not inside_plus:
        return n
    # Ambiguous (a sliver at the exit): point away from the centre.
    return n if float(np.dot(mid - np.asarray(asr.centre), n)) >= 0.0 else -n
