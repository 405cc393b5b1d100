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
    seg = surf.segments
    m = len(seg)
    t0, t1 = np.zeros(m), np.ones(m)
    alive = np.ones(m, dtype=bool)
    if len(covers):
        lo, hi = covers.lo, covers.hi
        k2 = 2.0 * np.arange(m)
        # surfaces wholly inside a cover were seen through it; those it lands on are trimmed
        alive = ~((k2[None, :] > lo[:, None] + 1e-9) & (k2[None, :] + 1 < hi[:, None] - 1e-9)).any(axis=0)
        klo, khi = (lo // 2).astype(int), (hi // 2).astype(int)
        a_ok = (klo < m) & (lo - 2 * klo <= 1.0)
        b_ok = (khi < m) & (hi - 2 * khi <= 1.0)
        np.minimum.at(t1, klo[a_ok], (lo - 2 * klo)[a_ok])
        np.maximum.at(t0, khi[b_ok], (hi - 2 * khi)[b_ok])
    alive &= t1 >= t0 - 1e-9
    starts = dict(zip(np.round(covers.lo, 9).tolist(), covers.label.tolist(), strict=True))

    kk = np.flatnonzero(alive)
    d = seg[kk, 1] - seg[kk, 0]
    a = seg[kk, 0] + t0[kk, None] * d
    b = seg[kk, 0] + t1[kk, None] * d
    v = np.empty((1 + 2 * len(kk), 2))
    v[0] = (-p.rear_closure, 0.0)
    v[1::2], v[2::2] = a, b
    ends = np.round(2 * kk + t1[kk], 9).tolist()
    same = (surf.cluster[kk[1:]] == surf.cluster[kk[:-1]]).tolist()
    labels = [UNKNOWN]
    for i, end in enumerate(ends):  # one step per surface, not per beam
        lab = starts.get(end)
        if lab is None:
            lab = SURFACE if i < len(same) and same[i] else UNKNOWN
        labels += (SURFACE, lab)
    labels[-1] = UNKNOWN  # from the last surface back round the unseen rear
    v, labels = _drop_repeats(v, labels)

    surfaces = np.stack([a, b], axis=1)
    closed = covers.label == CLOSED
    if closed.any():
        surfaces = np.concatenate([surfaces, np.stack([covers.a[closed], covers.b[closed]], axis=1)])
    ex = covers.label == EXIT
    exits = np.stack([covers.a[ex], covers.b[ex]], axis=1) if ex.any() else np.zeros((0, 2, 2))
    return View(v, labels, valid_polygon(v), surfaces, exits, covers.through_robot > 0)


def _drop_repeats(v: np.ndarray, labels: list[str]) -> tuple[np.ndarray, list[str]]:
    """Remove zero-length edges; the surviving edge keeps the label of the non-degenerate one."""
    d = np.concatenate([v[1:], v[:1]]) - v
    step = np.hypot(d[:, 0], d[:, 1])
    if (step > 1e-9).all():
        return v, labels
    keep = step > 1e-9  # vertex i is kept when its outgoing edge has length
    out_v = v[keep]
    out_l = [lab for lab, k in zip(labels, keep.tolist(), strict=True) if k]
    return out_v, out_l


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
