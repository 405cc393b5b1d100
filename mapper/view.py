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
    """

    vertices: np.ndarray
    labels: list[str]
    polygon: shapely.Polygon
    surfaces: np.ndarray
    exits: np.ndarray


def _point(seg: np.ndarray, k: int, t: float) -> np.ndarray:
    return seg[k, 0] + t * (seg[k, 1] - seg[k, 0])


def build_view(surf: Surfaces, p: MapperParams, covers: Covers | None = None) -> View:
    """The truncated, labelled view polygon of one scan; see the module docstring."""
    if covers is None:
        covers = find_covers(surf, p)
    seg = surf.segments
    m = len(seg)
    t0, t1 = np.zeros(m), np.ones(m)
    alive = np.ones(m, dtype=bool)
    k = np.arange(m)
    starts = {}
    for lo, hi, lab in zip(covers.lo.tolist(), covers.hi.tolist(), covers.label.tolist(), strict=True):
        # surfaces wholly inside the cover were seen through it; those it lands on are trimmed
        alive &= ~((2 * k > lo + 1e-9) & (2 * k + 1 < hi - 1e-9))
        klo, khi = int(lo // 2), int(hi // 2)
        if klo < m and lo - 2 * klo <= 1.0:
            t1[klo] = min(t1[klo], lo - 2 * klo)
        if khi < m and hi - 2 * khi <= 1.0:
            t0[khi] = max(t0[khi], hi - 2 * khi)
        starts[round(lo, 9)] = lab
    alive &= t1 >= t0 - 1e-9

    rear = np.array([-p.rear_closure, 0.0])
    verts: list[np.ndarray] = [rear]
    labels: list[str] = []
    pending = UNKNOWN
    kept = np.flatnonzero(alive).tolist()
    for i, kk in enumerate(kept):  # one step per surface, not per beam
        verts.append(_point(seg, kk, t0[kk]))
        labels.append(pending)
        verts.append(_point(seg, kk, t1[kk]))
        labels.append(SURFACE)
        lab = starts.get(round(2 * kk + t1[kk], 9))
        if lab is None:
            nxt = kept[i + 1] if i + 1 < len(kept) else None
            lab = SURFACE if nxt is not None and surf.cluster[nxt] == surf.cluster[kk] else UNKNOWN
        pending = lab
    labels.append(UNKNOWN)
    v = np.asarray(verts)
    v, labels = _drop_repeats(v, labels)

    kk = np.asarray(kept, dtype=int)
    d = seg[kk, 1] - seg[kk, 0]
    surfaces = np.stack([seg[kk, 0] + t0[kk, None] * d, seg[kk, 0] + t1[kk, None] * d], axis=1)
    closed = covers.label == CLOSED
    if closed.any():
        surfaces = np.concatenate([surfaces, np.stack([covers.a[closed], covers.b[closed]], axis=1)])
    ex = covers.label == EXIT
    exits = np.stack([covers.a[ex], covers.b[ex]], axis=1) if ex.any() else np.zeros((0, 2, 2))
    return View(v, labels, valid_polygon(v), surfaces, exits)


def _drop_repeats(v: np.ndarray, labels: list[str]) -> tuple[np.ndarray, list[str]]:
    """Remove zero-length edges; the surviving edge keeps the label of the non-degenerate one."""
    step = np.hypot(*(np.roll(v, -1, axis=0) - v).T)
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
