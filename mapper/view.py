"""The view polygon of one scan (method.md §2.3-2.4), robot frame, metres.

The visibility polygon of the scan truncated at its exits, built from the surfaces and the gap
covers of :mod:`mapper.exits` rather than from the beams: walking the sweep counter-clockwise,
each surface contributes its visible part; a cover (exit or closed gap) replaces everything the
sweep saw between its two ends, so surfaces seen *through* an exit (the room beyond a doorway) are
eliminated and the surfaces the cover lands on are trimmed at it. The unseen rear (the 180° behind
the scanner) is closed by two ``unknown`` edges through a point ``rear_closure`` behind the robot
centre, so the robot's own footprint, which is free space, lies inside the view.

Edge labels: along a surface or a closed gap -> ``surface``; along an exit -> ``exit``; everything
else (open gaps, the rear) -> ``unknown``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from mapper.exits import CLOSED, EXIT, Covers, find_covers
from mapper.jit import kernel
from mapper.lines import Surfaces
from mapper.params import MapperParams

UNKNOWN = "unknown"
SURFACE = "surface"


@dataclass(frozen=True, slots=True, eq=False)
class View:
    """One scan's view, robot frame (m).

    ``vertices`` (V, 2) counter-clockwise, not closed; ``labels[i]`` labels the edge from vertex i
    to vertex i+1 (cyclically). ``polygon``: the same ring as a valid shapely polygon (the largest
    part if the raw ring self-intersected). ``surfaces`` (S, 2, 2): visible surface parts and closed
    gaps (what the boundary may follow as ``surface``); ``exits`` (E, 2, 2): the exits.
    ``in_doorway``: the robot stood in a gap wide enough to pass (the exit across it ran through its
    centre and was left out, :func:`mapper.exits.find_covers`), so the view is not bounded there.
    """

    vertices: np.ndarray
    labels: list[str]
    polygon: shapely.Polygon
    surfaces: np.ndarray
    exits: np.ndarray
    in_doorway: bool = False


def build_view(surf: Surfaces, p: MapperParams, covers: Covers | None = None) -> View:
    """The truncated, labelled view polygon of one scan; see the module docstring."""
    if covers is None:
        covers = find_covers(surf, p)
    v, keep, surfaces, ends, same = _ring(surf.segments, covers.lo, covers.hi, surf.cluster, p.rear_closure)
    starts = dict(zip(np.round(covers.lo, 9).tolist(), covers.label.tolist(), strict=True))
    labels = [UNKNOWN]
    same = same.tolist()
    for i, end in enumerate(np.round(ends, 9).tolist()):  # one step per surface, not per beam
        lab = starts.get(end)
        if lab is None:
            lab = SURFACE if i < len(same) and same[i] else UNKNOWN
        labels += (SURFACE, lab)
    labels[-1] = UNKNOWN  # from the last surface back round the unseen rear
    if not keep.all():  # zero-length edges: the surviving edge keeps the non-degenerate one's label
        v = v[keep]
        labels = [lab for lab, k in zip(labels, keep.tolist(), strict=True) if k]

    closed = covers.label == CLOSED
    if closed.any():
        surfaces = np.concatenate([surfaces, np.stack([covers.a[closed], covers.b[closed]], axis=1)])
    ex = covers.label == EXIT
    exits = np.stack([covers.a[ex], covers.b[ex]], axis=1) if ex.any() else np.zeros((0, 2, 2))
    return View(v, labels, valid_polygon(v), surfaces, exits, covers.through_robot > 0)


@kernel
def _ring(
    seg: np.ndarray, lo: np.ndarray, hi: np.ndarray, cluster: np.ndarray, rear_closure: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`build_view`'s ring from the surfaces ``seg`` (M, 2, 2) and the covers' sweep positions
    ``lo``, ``hi`` (N,) (robot frame, m), compiled (:mod:`mapper.jit`). Replaces the numpy form::

        alive = ~((k2[None, :] > lo[:, None] + 1e-9) & (k2[None, :] + 1 < hi[:, None] - 1e-9)).any(axis=0)
        np.minimum.at(t1, klo[a_ok], (lo - 2 * klo)[a_ok])   # surfaces a cover lands on: trimmed
        np.maximum.at(t0, khi[b_ok], (hi - 2 * khi)[b_ok])
        alive &= t1 >= t0 - 1e-9; kk = flatnonzero(alive)
        v = [(-rear_closure, 0), a_0, b_0, a_1, ...]; a, b = seg[kk, 0] + t0 / t1 * d
        keep = hypot(*(roll(v, -1) - v).T) > 1e-9               # no zero-length edges

    Returns the vertices v (1 + 2 K, 2), which of them to keep (their outgoing edge has length),
    the visible surface parts (K, 2, 2), each part's end sweep position ``2 kk + t1`` (K,) (not yet
    rounded) and whether consecutive parts share a breakpoint cluster (K - 1,). hypot is libm's, as
    numpy's ``np.hypot``."""
    m = seg.shape[0]
    nc = lo.shape[0]
    t0, t1 = np.zeros(m), np.ones(m)
    alive = np.ones(m, dtype=np.bool_)
    for k in range(m):
        k2 = 2.0 * k
        for c in range(nc):
            if k2 > lo[c] + 1e-9 and k2 + 1 < hi[c] - 1e-9:
                alive[k] = False
                break
    for c in range(nc):  # in order, as np.minimum.at
        klo = int(lo[c] // 2)
        f = lo[c] - 2 * klo
        if klo < m and f <= 1.0:
            t1[klo] = min(t1[klo], f)
    for c in range(nc):
        khi = int(hi[c] // 2)
        f = hi[c] - 2 * khi
        if khi < m and f <= 1.0:
            t0[khi] = max(t0[khi], f)
    for k in range(m):
        alive[k] = alive[k] and t1[k] >= t0[k] - 1e-9
    kk = np.flatnonzero(alive)
    n = len(kk)
    v = np.empty((1 + 2 * n, 2))
    v[0, 0], v[0, 1] = -rear_closure, 0.0
    surfaces = np.empty((n, 2, 2))
    ends = np.empty(n)
    same = np.empty(max(n - 1, 0), dtype=np.bool_)
    for i in range(n):
        k = kk[i]
        dx, dy = seg[k, 1, 0] - seg[k, 0, 0], seg[k, 1, 1] - seg[k, 0, 1]
        surfaces[i, 0, 0], surfaces[i, 0, 1] = seg[k, 0, 0] + t0[k] * dx, seg[k, 0, 1] + t0[k] * dy
        surfaces[i, 1, 0], surfaces[i, 1, 1] = seg[k, 0, 0] + t1[k] * dx, seg[k, 0, 1] + t1[k] * dy
        v[1 + 2 * i, 0], v[1 + 2 * i, 1] = surfaces[i, 0, 0], surfaces[i, 0, 1]
        v[2 + 2 * i, 0], v[2 + 2 * i, 1] = surfaces[i, 1, 0], surfaces[i, 1, 1]
        ends[i] = 2 * k + t1[k]
        if i > 0:
            same[i - 1] = cluster[k] == cluster[kk[i - 1]]
    nv = v.shape[0]
    keep = np.empty(nv, dtype=np.bool_)
    for i in range(nv):
        nxt = i + 1 if i + 1 < nv else 0
        keep[i] = np.hypot(v[nxt, 0] - v[i, 0], v[nxt, 1] - v[i, 1]) > 1e-9
    return v, keep, surfaces, ends, same


def valid_polygon(v: np.ndarray) -> shapely.Polygon:
    """A valid polygon from a ring that may touch or cross itself: the part holding the origin
    (the robot, for a view), else the largest valid part."""
    poly = shapely.Polygon(v) if len(v) >= 3 else shapely.Polygon()
    if poly.is_valid:
        return poly
    fixed = shapely.make_valid(poly)
    parts = shapely.get_parts(fixed)
    polys = [q for g in parts for q in shapely.get_parts(g) if isinstance(q, shapely.Polygon)]
    if not polys:
        return shapely.Polygon()
    origin = shapely.Point(0.0, 0.0)
    holding = [q for q in polys if q.covers(origin)]
    return max(holding or polys, key=lambda q: q.area)
