"""Surfaces from one laser scan (method.md §1): breakpoints, split-and-merge, total least squares.

1. Beams become points in the **robot frame** (the laser's mounting offset applied).
2. The sweep breaks into clusters where a no-return (or invalid) reading intervenes or consecutive
   points jump farther than Borges & Aldon's adaptive breakpoint distance
   ``D = r * sin(dphi) / sin(lambda - dphi) + 3 sigma`` (floored at ``breakpoint_floor``).
3. Each cluster is split recursively at the point farthest from its chord (iterative end-point
   fit), in one compiled loop (:mod:`mapper.jit`; no Python loop runs per beam or per segment).
4. Every piece is fitted by orthogonal (total least squares) regression; neighbouring pieces of one
   cluster whose lines agree are merged and refitted. Endpoints are the first and last points
   projected onto the fitted line.
5. A cluster of one point (a chair or table leg) becomes a short surface across its beam.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from mapper.jit import kernel
from mapper.params import MapperParams
from mapper.types import Scan


@dataclass(frozen=True, slots=True, eq=False)
class ScanPoints:
    """The valid returns of one scan in the robot frame (m).

    ``xy`` (K, 2) points; ``beam`` (K,) their beam indices; ``rng`` (K,) ranges (m);
    ``origin``: the laser position (m, robot frame), the viewpoint of every beam;
    ``gap_no_return`` (K,) True where a no-return reading lies between point k-1 and point k.
    """

    xy: np.ndarray
    beam: np.ndarray
    rng: np.ndarray
    origin: tuple[float, float]
    gap_no_return: np.ndarray
    angle_increment: float


@dataclass(frozen=True, slots=True, eq=False)
class Surfaces:
    """Line segments fitted to one scan, in angular (beam) order, robot frame (m).

    ``segments`` (M, 2, 2): ``segments[j, 0]`` is the end at the lower beam index (clockwise end),
    ``segments[j, 1]`` the other. ``beams`` (M, 2): first and last beam index of each;
    ``pidx`` (M, 2): first and last index into ``points.xy``; ``cluster`` (M,): breakpoint cluster.
    """

    segments: np.ndarray
    beams: np.ndarray
    pidx: np.ndarray
    cluster: np.ndarray
    points: ScanPoints

    def __len__(self) -> int:
        return len(self.segments)


@functools.lru_cache(maxsize=8)
def _trig(n: int, angle_min: float, inc: float, laser_theta: float) -> tuple[np.ndarray, np.ndarray]:
    a = angle_min + inc * np.arange(n) + laser_theta
    return np.cos(a), np.sin(a)


def scan_points(scan: Scan, p: MapperParams) -> ScanPoints:
    """Valid returns of ``scan`` as robot-frame points (m); see :class:`ScanPoints`."""
    r = np.asarray(scan.ranges, dtype=float)
    c, s = _trig(len(r), float(scan.angle_min), float(scan.angle_increment), p.laser_theta)
    xy, beam, rv, gap = _points(r, c, s, float(scan.max_range), p.min_range, p.laser_x, p.laser_y)
    return ScanPoints(xy, beam, rv, (p.laser_x, p.laser_y), gap, float(scan.angle_increment))


@kernel
def _points(r: np.ndarray, c: np.ndarray, s: np.ndarray, max_range: float, min_range: float,
            lx: float, ly: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`scan_points`' arrays from the ranges ``r`` (m) and each beam's cos and sin (robot
    frame): a valid return is finite, below ``max_range`` and above ``min_range``; a no-return is
    not finite or at least ``max_range`` (m); ``gap`` marks a no-return strictly between two
    consecutive valid beams. Compiled (:mod:`mapper.jit`): one pass instead of about 15 numpy
    calls."""
    n = r.shape[0]
    beam = np.empty(n, np.int64)
    k = 0
    gap = np.zeros(n, np.bool_)
    missing = False  # a no-return since the last valid beam
    for i in range(n):
        v = r[i]
        if not math.isfinite(v) or v >= max_range:
            missing = True
        elif v > min_range:
            gap[k] = missing and k > 0
            beam[k] = i
            k += 1
            missing = False
    beam = beam[:k].copy()
    xy = np.empty((k, 2))
    rv = np.empty(k)
    for j in range(k):
        b = beam[j]
        rv[j] = r[b]
        xy[j, 0] = lx + r[b] * c[b]
        xy[j, 1] = ly + r[b] * s[b]
    return xy, beam, rv, gap[:k].copy()


def _breaks(pts: ScanPoints, p: MapperParams) -> np.ndarray:
    """Boolean (K,): True where point k starts a new cluster (Borges & Aldon breakpoints)."""
    k = len(pts.beam)
    brk = np.ones(k, dtype=bool)
    if k < 2:
        return brk
    dphi = np.diff(pts.beam) * abs(pts.angle_increment)
    step = np.hypot(*np.diff(pts.xy, axis=0).T)
    den = np.sin(p.breakpoint_lambda - dphi)
    with np.errstate(divide="ignore", invalid="ignore"):
        dmax = np.where(den > 0, pts.rng[:-1] * np.sin(dphi) / den, 0.0) + 3.0 * p.breakpoint_sigma
    dmax = np.maximum(dmax, p.breakpoint_floor)
    brk[1:] = (step > dmax) | (den <= 0) | pts.gap_no_return[1:] | (np.diff(pts.beam) > 1)
    return brk


@kernel
def _split(xy: np.ndarray, s: np.ndarray, e: np.ndarray, thr: float) -> tuple[np.ndarray, np.ndarray]:
    """Iterative end-point fit: each cluster (points ``s[i]..e[i]``) split at the first of its
    inner points farthest from its chord while that is more than ``thr`` (m) away. Returns the
    pieces' (start, end) point indices in sweep order. Compiled (:mod:`mapper.jit`)."""
    out_s = np.empty(len(xy), dtype=np.int64)
    out_e = np.empty(len(xy), dtype=np.int64)
    n = 0
    stack = np.empty((len(xy) + 1, 2), dtype=np.int64)  # pieces to do; the top is the leftmost
    for c in range(len(s)):
        stack[0, 0], stack[0, 1] = s[c], e[c]
        top = 1
        while top:
            top -= 1
            a, b = stack[top, 0], stack[top, 1]
            far, at = -1.0, -1
            if b - a >= 2:
                ax, ay = xy[a, 0], xy[a, 1]
                abx, aby = xy[b, 0] - ax, xy[b, 1] - ay
                norm = max(math.hypot(abx, aby), 1e-9)
                for k in range(a + 1, b):
                    d = abs(abx * (xy[k, 1] - ay) - aby * (xy[k, 0] - ax)) / norm
                    if d > far:
                        far, at = d, k
            if far > thr:
                stack[top, 0], stack[top, 1] = at, b
                stack[top + 1, 0], stack[top + 1, 1] = a, at
                top += 2
            else:
                out_s[n], out_e[n] = a, b
                n += 1
    return out_s[:n], out_e[:n]


@kernel
def _fit(xy: np.ndarray, s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total least squares lines of the pieces (points ``s[i]..e[i]``): centroids (M, 2) and unit
    directions (M, 2), robot frame. Compiled (:mod:`mapper.jit`)."""
    m = len(s)
    c = np.empty((m, 2))
    u = np.empty((m, 2))
    for i in range(m):
        n = e[i] - s[i] + 1
        cx = cy = 0.0
        for k in range(s[i], e[i] + 1):
            cx += xy[k, 0]
            cy += xy[k, 1]
        cx /= n
        cy /= n
        sxx = syy = sxy = 0.0
        for k in range(s[i], e[i] + 1):
            qx, qy = xy[k, 0] - cx, xy[k, 1] - cy
            sxx += qx * qx
            syy += qy * qy
            sxy += qx * qy
        phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
        c[i, 0], c[i, 1] = cx, cy
        u[i, 0], u[i, 1] = math.cos(phi), math.sin(phi)
    return c, u


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the 2-D cross products of rows (np.cross on 2-vectors is deprecated and slow)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


_SNAP_SIN = math.sin(math.radians(20.0))  # pieces' lines meeting at less than 20 degrees: no corner


@kernel
def _ends(xy: np.ndarray, s: np.ndarray, e: np.ndarray, c: np.ndarray, u: np.ndarray, cluster: np.ndarray,
          ox: float, oy: float, snap: float, snap_sin: float, half: float) -> np.ndarray:
    """The surfaces (M, 2, 2) of the pieces (points ``s[i]..e[i]``, lines through ``c`` along unit
    ``u``), robot frame (m), compiled (:mod:`mapper.jit`). Replaces the numpy form::

        ta = einsum("ij,ij->i", xy[s] - c, u); seg = stack([c + ta u, c + tb u])  # ends projected
        # corners: neighbours of one cluster whose lines cross at more than asin(snap_sin) join at
        # the intersection x when it is within ``snap`` (m) of both ends (hypot, libm's as numpy's)
        t = cross(c[1:] - c[:-1], u[1:]) / cross(u[:-1], u[1:]); x = c[:-1] + t u[:-1]
        seg[j, 1] = seg[j + 1, 0] = x[j]
        # a lone return (s == e, a leg): a surface 2 ``half`` m long across its beam from the laser
        # at (ox, oy), centred on the point
        t = [-dy, dx] / max(hypot(dx, dy), 1e-9); seg = [xy - half t, xy + half t]

    The corner steps are independent (step i reads seg[i, 1] and seg[i + 1, 0] before writing
    them), so one pass in order gives what the vectorised form gave."""
    m = s.shape[0]
    seg = np.empty((m, 2, 2))
    for i in range(m):
        ta = (xy[s[i], 0] - c[i, 0]) * u[i, 0] + (xy[s[i], 1] - c[i, 1]) * u[i, 1]
        tb = (xy[e[i], 0] - c[i, 0]) * u[i, 0] + (xy[e[i], 1] - c[i, 1]) * u[i, 1]
        seg[i, 0, 0], seg[i, 0, 1] = c[i, 0] + ta * u[i, 0], c[i, 1] + ta * u[i, 1]
        seg[i, 1, 0], seg[i, 1, 1] = c[i, 0] + tb * u[i, 0], c[i, 1] + tb * u[i, 1]
    for i in range(m - 1):
        den = u[i, 0] * u[i + 1, 1] - u[i, 1] * u[i + 1, 0]
        if cluster[i] != cluster[i + 1] or not abs(den) > snap_sin:
            continue
        dcx, dcy = c[i + 1, 0] - c[i, 0], c[i + 1, 1] - c[i, 1]
        t = (dcx * u[i + 1, 1] - dcy * u[i + 1, 0]) / den
        x0, x1 = c[i, 0] + t * u[i, 0], c[i, 1] + t * u[i, 1]
        if (np.hypot(x0 - seg[i, 1, 0], x1 - seg[i, 1, 1]) < snap
                and np.hypot(x0 - seg[i + 1, 0, 0], x1 - seg[i + 1, 0, 1]) < snap):
            seg[i, 1, 0], seg[i, 1, 1] = x0, x1
            seg[i + 1, 0, 0], seg[i + 1, 0, 1] = x0, x1
    for i in range(m):
        if s[i] != e[i]:
            continue
        px, py = xy[s[i], 0], xy[s[i], 1]
        dx, dy = px - ox, py - oy
        n = max(np.hypot(dx, dy), 1e-9)
        tx, ty = -dy / n, dx / n
        seg[i, 0, 0], seg[i, 0, 1] = px - half * tx, py - half * ty
        seg[i, 1, 0], seg[i, 1, 1] = px + half * tx, py + half * ty
    return seg


def extract_surfaces(pts: ScanPoints, p: MapperParams) -> Surfaces:
    """Fit surfaces to the points of one scan (robot frame, m); see the module docstring."""
    xy = pts.xy
    k = len(xy)
    if k == 0:
        empty = np.zeros((0, 2), dtype=int)
        return Surfaces(np.zeros((0, 2, 2)), empty, empty, np.zeros(0, dtype=int), pts)
    brk = _breaks(pts, p)
    cs = np.flatnonzero(brk)
    ce = np.append(cs[1:] - 1, k - 1)
    s, e = _split(xy, cs, ce, p.split_threshold)
    cluster = np.cumsum(brk)[s] - 1
    c, u = _fit(xy, s, e)
    if len(s) > 1:
        # merge neighbours of one cluster whose lines agree (split can overshoot on noisy walls)
        cosang = np.abs(np.einsum("ij,ij->i", u[:-1], u[1:]))
        shared = xy[e[:-1]]
        off1 = np.abs(_cross(u[:-1], shared - c[:-1]))
        off2 = np.abs(_cross(u[1:], shared - c[1:]))
        merge = (
            (cluster[:-1] == cluster[1:])
            & (cosang > math.cos(p.merge_angle))
            & (off1 < p.merge_distance)
            & (off2 < p.merge_distance)
        )
        if merge.any():
            keep = np.append(True, ~merge)
            last = np.append(np.flatnonzero(keep)[1:] - 1, len(s) - 1)
            s, e, cluster = s[keep], e[last], cluster[keep]
            c, u = _fit(xy, s, e)
    if len(s) > 2:
        # a two-point piece between two pieces of its cluster only bridges a corner that fell
        # between two beams: drop it and let the corner snapping below join its neighbours
        same = cluster[:-1] == cluster[1:]
        bridge = np.zeros(len(s), dtype=bool)
        bridge[1:-1] = (e - s == 1)[1:-1] & same[:-1] & same[1:]
        if bridge.any():
            s, e, cluster, c, u = s[~bridge], e[~bridge], cluster[~bridge], c[~bridge], u[~bridge]
    seg = _ends(xy, s, e, c, u, cluster, float(pts.origin[0]), float(pts.origin[1]), p.corner_snap,
                _SNAP_SIN, 0.5 * p.point_surface_length)
    beams = np.stack([pts.beam[s], pts.beam[e]], axis=1)
    return Surfaces(seg, beams, np.stack([s, e], axis=1), cluster, pts)
