"""Geometry of the cycle check: ASRs in the global frame, a spatial index, overlap and surface alignment.

Everything here is in the *global frame* (m, rad) unless a name says otherwise. The index answers
"which ASRs' polygons contain this point" in O(log² N + k) with shapely STRtrees kept by the
logarithmic method (Bentley & Saxe): trees of sizes 1, 2, 4, ... that are merged when two of equal
size exist, so adding an ASR costs O(log N) amortised rebuild work and a query visits O(log N)
trees of O(log N) depth. Changed polygons are re-added; stale entries are skipped by version.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from mapper.jit import kernel
from mapper.nearest import point_tree
from mapper.se2 import Pose, compose, transform_points, wrap
from mapper.types import ASR

PARALLEL = math.cos(math.radians(20.0))  # |cos| of two directions within 20° of each other


def global_polygon(asr: ASR, origin: Pose | None = None) -> shapely.Polygon:
    """The ASR's polygon in the global frame (its ``origin``, or the one given), made valid.

    A self-touching boundary (possible after simplification) is repaired with ``make_valid`` and the
    largest polygonal part kept: the cycle check needs one area, not slivers.
    """
    pts = transform_points(asr.origin if origin is None else origin, asr.boundary)
    poly = shapely.Polygon(pts) if len(pts) >= 3 else shapely.Polygon()
    if not poly.is_valid:
        fixed = shapely.make_valid(poly)
        parts = [g for g in shapely.get_parts(fixed) if isinstance(g, shapely.Polygon)]
        if not parts:
            return shapely.Polygon()
        poly = max(parts, key=lambda g: g.area)
    return poly


def global_centre(asr: ASR, origin: Pose | None = None) -> tuple[float, float]:
    """The ASR's centre (method.md §3) in the global frame (m)."""
    p = transform_points(asr.origin if origin is None else origin, np.asarray(asr.centre, dtype=float))[0]
    return (float(p[0]), float(p[1]))


def centre_of(polygon: shapely.Geometry) -> tuple[tuple[float, float], str]:
    """An ASR's centre (method.md §3) from its polygon, in the polygon's frame (m), and the rule
    that gave it: the centroid (``"centroid"``), or a representative point inside when the
    centroid falls outside a concave polygon (``"point_on_surface"``)."""
    c = polygon.centroid
    if polygon.contains(c):
        return (float(c.x), float(c.y)), "centroid"
    c = polygon.point_on_surface()
    return (float(c.x), float(c.y)), "point_on_surface"


def depth_inside(polygon: shapely.Geometry, point: tuple[float, float]) -> float:
    """Signed distance (m) of ``point`` from ``polygon``'s boundary, both in one frame: positive
    inside, negative outside; -inf for an empty polygon."""
    if polygon.is_empty:
        return -math.inf
    pt = shapely.Point(point)
    d = float(polygon.boundary.distance(pt))
    return d if polygon.covers(pt) else -d


def axis_depth(polygon: shapely.Geometry, point: tuple[float, float], axis: float, reach: float = 100.0
               ) -> float:
    """How far (m) ``point`` can move along the direction ``axis`` (rad), either way, before it
    leaves ``polygon`` (both in one frame): the nearer of the two boundary crossings, at most
    ``reach``; 0 when the point lies outside."""
    pt = shapely.Point(point)
    if polygon.is_empty or not polygon.covers(pt):
        return 0.0
    dx, dy = reach * math.cos(axis), reach * math.sin(axis)
    line = shapely.LineString([(point[0] - dx, point[1] - dy), (point[0] + dx, point[1] + dy)])
    hits = shapely.get_coordinates(shapely.intersection(line, polygon.boundary))
    if len(hits) == 0:
        return reach
    t = (hits[:, 0] - point[0]) * math.cos(axis) + (hits[:, 1] - point[1]) * math.sin(axis)
    ahead, behind = t[t >= 0], -t[t <= 0]
    return float(min(ahead.min() if len(ahead) else reach, behind.min() if len(behind) else reach))


def iou(a: shapely.Geometry, b: shapely.Geometry) -> float:
    """Intersection over union of two areas (0..1); 0 for empty geometry."""
    union = shapely.union(a, b).area
    return float(shapely.intersection(a, b).area / union) if union > 0 else 0.0


class SpatialIndex:
    """Polygons by integer id, queried by point (the logarithmic method over shapely STRtrees)."""

    def __init__(self) -> None:
        self._geoms: dict[int, shapely.Geometry] = {}
        self._version: dict[int, int] = {}
        # Each level: (tree, ids, versions); sizes kept roughly distinct powers of two.
        self._levels: list[tuple[shapely.STRtree, np.ndarray, np.ndarray]] = []

    def __len__(self) -> int:
        return len(self._geoms)

    def __contains__(self, key: int) -> bool:
        return key in self._geoms

    def geometry(self, key: int) -> shapely.Geometry:
        return self._geoms[key]

    def upsert(self, key: int, geom: shapely.Geometry) -> None:
        """Add or replace the polygon of ``key``."""
        self._geoms[key] = geom
        self._version[key] = self._version.get(key, -1) + 1
        ids, vers = np.array([key]), np.array([self._version[key]])
        while self._levels and len(self._levels[-1][1]) <= len(ids):
            _, lids, lvers = self._levels.pop()
            ids, vers = np.concatenate([lids, ids]), np.concatenate([lvers, vers])
        live = np.array([self._version.get(int(i)) == int(v) for i, v in zip(ids, vers, strict=True)])
        ids, vers = ids[live], vers[live]
        if len(ids):
            self._levels.append((shapely.STRtree([self._geoms[int(i)] for i in ids]), ids, vers))

    def remove(self, key: int) -> None:
        self._geoms.pop(key, None)
        self._version[key] = self._version.get(key, -1) + 1

    def rebuild(self, geoms: dict[int, shapely.Geometry]) -> None:
        """Replace everything (after a realignment moved every ASR): one tree."""
        self._geoms = dict(geoms)
        self._version = {k: self._version.get(k, -1) + 1 for k in set(self._version) | set(geoms)}
        self._levels = []
        if geoms:
            ids = np.array(sorted(geoms))
            vers = np.array([self._version[int(i)] for i in ids])
            self._levels.append((shapely.STRtree([geoms[int(i)] for i in ids]), ids, vers))

    def containing(self, x: float, y: float, radius: float = 0.0) -> list[int]:
        """Ids whose polygon contains (or touches) the point (x, y), or, with ``radius`` > 0 (m),
        comes within ``radius`` of it; ascending."""
        pt = shapely.Point(x, y) if radius <= 0 else shapely.Point(x, y).buffer(radius, quad_segs=4)
        out = set()
        for tree, ids, vers in self._levels:
            for n in tree.query(pt, predicate="intersects"):
                k, v = int(ids[n]), int(vers[n])
                if self._version.get(k) == v and k in self._geoms:
                    out.add(k)
        return sorted(out)


def surface_points(asr: ASR, spacing: float, origin: Pose | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 2) every ``spacing`` m along the ASR's ``surface`` edges and their unit normals
    (N, 2) pointing into the ASR, both in the global frame."""
    b = np.asarray(asr.boundary, dtype=float)
    if len(b) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    nxt = np.roll(b, -1, axis=0)
    is_surface = np.array([e == "surface" for e in asr.edges[: len(b)]], dtype=bool)
    if len(is_surface) < len(b):
        is_surface = np.concatenate([is_surface, np.zeros(len(b) - len(is_surface), dtype=bool)])
    a, c = b[is_surface], nxt[is_surface]
    lengths = np.hypot(*(c - a).T)
    keep = lengths > 1e-9
    a, c, lengths = a[keep], c[keep], lengths[keep]
    counts = np.maximum(1, np.ceil(lengths / spacing).astype(int))
    seg = np.repeat(np.arange(len(a)), counts)
    # Fractions (k + 0.5) / count along each edge: no point is shared by two edges.
    frac = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + 0.5) / counts[seg]
    pts = a[seg] + frac[:, None] * (c[seg] - a[seg])
    d = (c - a) / lengths[:, None]
    # Left of each edge is inside for a counter-clockwise boundary; flip for a clockwise one.
    inward = 1.0 if float(np.sum(b[:, 0] * nxt[:, 1] - nxt[:, 0] * b[:, 1])) >= 0 else -1.0
    normals = inward * np.c_[-d[:, 1], d[:, 0]][seg]
    pose = asr.origin if origin is None else origin
    rot = transform_points((0.0, 0.0, pose[2]), normals)
    return transform_points(pose, pts), rot


@dataclass(frozen=True, slots=True)
class Alignment:
    """Result of aligning point set P onto Q: ``correction`` is the global-frame rigid motion
    (m, m, rad) that moves P onto Q; ``rms`` (m) of inlier point-to-surface distances after it,
    ``inliers`` the fraction of P within the inlier distance, ``shift`` (m) how far P's centroid moved."""

    correction: Pose
    rms: float
    inliers: float
    shift: float
    constraint: float = 0.0
    """Smallest eigenvalue of the matched surfaces' normal scatter (mean n nᵀ of unit normals), 0..0.5:
    0 when every matched surface is parallel (a straight corridor, where the alignment along it is
    unobserved), 0.5 when they face every way equally (a room's four walls)."""
    axis: float = 0.0
    """rad, global frame: the direction of translation the matched surfaces constrain least (the
    eigenvector of ``constraint``): along a corridor, the corridor's direction."""
    violation: float = 0.0
    """Fraction of surface points that, after the alignment, lie inside the other ASR's free space
    (deeper than a margin into its polygon): walls where the other place has none. Set by the caller."""
    pinned: float | None = None
    """m: when the surfaces left ``axis`` open and the two ASRs' exits fixed it (:func:`exit_pin`),
    the shift along ``axis`` that was added to ``correction``; None otherwise. Set by the caller."""
    across: float = 0.0
    """m: how far apart across ``axis`` the matched points of P lie once aligned (5th to 95th
    percentile of their offsets along the axis's normal): about 0 when one wall carries the whole
    match, a corridor's width when both its walls do."""


def exit_segments(asr: ASR, origin: Pose | None = None) -> np.ndarray:
    """The ASR's exits as segments (E, 2, 2) in the global frame (placed at its ``origin``, or the
    one given), m."""
    if not asr.exits:
        return np.zeros((0, 2, 2))
    ends = np.array([[e.a, e.b] for e in asr.exits], dtype=float).reshape(-1, 2)
    return transform_points(asr.origin if origin is None else origin, ends).reshape(-1, 2, 2)


def exit_pin(seg_p: np.ndarray, seg_q: np.ndarray, axis: float, tolerance: float, reach: float
             ) -> tuple[float, int] | None:
    """Where along ``axis`` (rad) the exits of one ASR meet those of another, both (E, 2, 2) in one
    frame (m): the shift s (m) that moves P's exits along the axis onto Q's, and how many pairs agree
    on it. Two exits are a pair when, shifted, their midpoints lie within ``tolerance`` (m) of each
    other, they are parallel to within 20° and their widths differ by at most ``tolerance``.

    A straight corridor's walls leave the position along it open (:attr:`Alignment.axis`); its
    doorways and ends do not. None unless the pair needing the smallest shift is within ``reach``
    (m: how far the drift can have put them apart) and every pair within ``reach`` agrees with it
    (within ``tolerance``): a row of like doorways closer than the drift cannot say which is which.
    """
    if len(seg_p) == 0 or len(seg_q) == 0 or reach <= 0:
        return None
    d = np.array([math.cos(axis), math.sin(axis)])
    normal = np.array([-d[1], d[0]])
    vp, vq = seg_p[:, 1] - seg_p[:, 0], seg_q[:, 1] - seg_q[:, 0]
    wp, wq = np.hypot(vp[:, 0], vp[:, 1]), np.hypot(vq[:, 0], vq[:, 1])
    off = seg_q.mean(axis=1)[None, :, :] - seg_p.mean(axis=1)[:, None, :]  # (P, Q, 2)
    along, across = off @ d, off @ normal
    cos = np.abs(vp @ vq.T) / np.maximum(np.outer(wp, wq), 1e-12)
    alike = (cos >= PARALLEL) & (np.abs(wp[:, None] - wq[None, :]) <= tolerance)
    pair = alike & (np.abs(across) <= tolerance) & (np.abs(along) <= reach)
    shifts = along[pair]
    if len(shifts) == 0:
        return None
    s = float(shifts[np.argmin(np.abs(shifts))])
    agree = np.abs(shifts - s) <= tolerance
    if not agree.all():
        return None
    return float(np.mean(shifts[agree])), int(np.count_nonzero(agree))


def free_space_violation(points: np.ndarray, polygon: shapely.Geometry, margin: float) -> float:
    """Fraction of ``points`` (N, 2) lying more than ``margin`` (m) inside ``polygon``: surfaces seen in
    a space the polygon says is free. 0 for no points or an empty polygon."""
    if len(points) == 0 or polygon.is_empty:
        return 0.0
    inner = polygon.buffer(-margin)
    if inner.is_empty:
        return 0.0
    return float(np.mean(shapely.contains_xy(inner, points[:, 0], points[:, 1])))


@kernel
def first_facing(
    d: np.ndarray, j: np.ndarray, q_normals: np.ndarray, p_normals: np.ndarray, c: float, s: float
) -> tuple[np.ndarray, np.ndarray]:
    """For each point of P, of its k nearest points of Q (a kd-tree's answer: distances ``d``
    (N, k), m, inf past the gate; indices ``j`` (N, k), len(Q) past the gate) the first within the
    gate whose unit normal (``q_normals`` (M, 2)) faces within 60° of the point's own
    (``p_normals`` (N, 2) turned by the angle whose cosine and sine are ``c``, ``s``): whether there
    is one, and its index (the nearest's, clipped to Q, where there is none). One frame. Compiled
    (:mod:`mapper.jit`): it replaces the dozen numpy calls of each step of :func:`align_points`."""
    n, k = j.shape
    last = q_normals.shape[0] - 1
    ok, out = np.zeros(n, dtype=np.bool_), np.empty(n, dtype=np.int64)
    for i in range(n):
        fx = c * p_normals[i, 0] - s * p_normals[i, 1]  # P's normal, turned with P
        fy = s * p_normals[i, 0] + c * p_normals[i, 1]
        out[i] = min(j[i, 0], last)
        for m in range(k):
            jm = min(j[i, m], last)
            if d[i, m] < np.inf and q_normals[jm, 0] * fx + q_normals[jm, 1] * fy > 0.5:
                ok[i], out[i] = True, jm
                break
    return ok, out


def align_points(
    p: np.ndarray,
    q: np.ndarray,
    q_normals: np.ndarray,
    inlier_distance: float,
    start_distance: float = 1.0,
    iterations: int = 30,
    p_normals: np.ndarray | None = None,
) -> Alignment | None:
    """Trimmed point-to-plane ICP of P (N, 2) onto surfaces sampled as Q (M, 2) with unit normals.

    With ``p_normals`` (the unit normals of P's surfaces, pointing into P's ASR like Q's), a point
    only corresponds to one of its 4 nearest Q points whose surface faces the same way (within 60°):
    a room's west wall never pairs with the east wall, even when drift put it nearer.

    Global frame, metres. Each step solves the linearised least squares for (dθ, dx, dy) of
    Σ ((R p + t - q)·n)², damped (Levenberg) so that a direction the surfaces do not constrain
    (along a straight corridor) stays put instead of sliding. The correspondence gate shrinks from
    ``start_distance`` to ``inlier_distance``, so a drift of about a metre is pulled in without
    letting far, unrelated walls vote. None when a set has fewer than 10 points or nothing corresponds.
    """
    if len(p) < 10 or len(q) < 10:
        return None
    tree = point_tree(q)
    k = min(4, len(q))
    q_normals = np.ascontiguousarray(q_normals, dtype=float)
    if p_normals is not None:
        p_normals = np.ascontiguousarray(p_normals, dtype=float)
    ramp = max(2, (2 * iterations) // 3)
    gates = np.geomspace(start_distance, inlier_distance, ramp).tolist()
    gates += [inlier_distance] * (iterations - ramp)
    damping = 1e-3 * len(p)

    def nearest(pts: np.ndarray, rot: float, gate: float) -> tuple[np.ndarray, np.ndarray]:
        """(matched?, index into Q) for each point of ``pts`` (P moved by the current estimate)."""
        if p_normals is None:
            d, j = tree.query(pts, distance_upper_bound=gate)
            return d < np.inf, np.minimum(j, len(q) - 1)
        d, j = tree.query(pts, k=k, distance_upper_bound=gate)
        return first_facing(d, j.astype(np.int64), q_normals, p_normals, math.cos(rot), math.sin(rot))

    tx = ty = th = 0.0  # the estimate so far: P moved by (tx, ty, th) is ``cur``
    cur = p
    for gate in gates:
        ok, j = nearest(cur, th, gate)
        if np.count_nonzero(ok) < 10:
            return None
        pp, jo = cur[ok], j[ok]
        qq, nn = q[jo], q_normals[jo]
        # Rotation about the matched points' centroid keeps the system well conditioned.
        m = pp.mean(axis=0)
        r = pp - m
        n0, n1 = nn[:, 0], nn[:, 1]
        jac_t = np.stack([r[:, 0] * n1 - r[:, 1] * n0, n0, n1])  # (3, N): d residual / (dθ, dx, dy)
        res = (qq[:, 0] - pp[:, 0]) * n0 + (qq[:, 1] - pp[:, 1]) * n1
        h = jac_t @ jac_t.T
        h[np.diag_indices(3)] += damping
        x0, x1, x2 = np.linalg.solve(h, jac_t @ res).tolist()
        m0, m1 = float(m[0]), float(m[1])
        c, s = math.cos(x0), math.sin(x0)
        tx, ty, th = compose((m0 + x1 - (c * m0 - s * m1), m1 + x2 - (s * m0 + c * m1), x0), (tx, ty, th))
        cur = transform_points((tx, ty, th), p)
        if gate == inlier_distance and abs(x0) + abs(x1) + abs(x2) < 1e-6:
            break
    ok, j = nearest(cur, th, inlier_distance)
    qq, nn = q[j[ok]], q_normals[j[ok]]
    dist = np.abs(np.einsum("ij,ij->i", cur[ok] - qq, nn))
    rms = float(np.sqrt(np.mean(dist**2))) if ok.any() else math.inf
    shift = float(np.hypot(*(cur.mean(axis=0) - p.mean(axis=0))))
    constraint, axis, across = 0.0, 0.0, 0.0
    if len(nn):
        w, v = np.linalg.eigh(nn.T @ nn / len(nn))
        constraint, axis = float(w[0]), float(math.atan2(v[1, 0], v[0, 0]))
        offsets = cur[ok] @ np.array([-math.sin(axis), math.cos(axis)])
        lo, hi = np.percentile(offsets, [5.0, 95.0]).tolist()
        across = hi - lo
    return Alignment((tx, ty, wrap(th)), rms, float(ok.mean()), shift, constraint, axis, across=across)
