"""Surfaces from one laser scan (method.md §1): breakpoints, split-and-merge, total least squares.

1. Beams become points in the **robot frame** (the laser's mounting offset applied).
2. The sweep breaks into clusters where a no-return (or invalid) reading intervenes or consecutive
   points jump farther than Borges & Aldon's adaptive breakpoint distance
   ``D = r * sin(dphi) / sin(lambda - dphi) + 3 sigma`` (floored at ``breakpoint_floor``).
3. Each cluster is split recursively at the point farthest from its chord (iterative end-point
   fit). All clusters split at once: each round is a handful of numpy operations over every point,
   and the rounds number the recursion depth (log of the points per cluster), so no Python loop
   runs per beam or per segment.
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
    finite = np.isfinite(r)
    no_return = ~finite | (r >= scan.max_range)
    valid = ~no_return & (r > p.min_range)
    beam = np.flatnonzero(valid)
    rv = r[beam]
    xy = np.empty((len(beam), 2))
    xy[:, 0] = p.laser_x + rv * c[beam]
    xy[:, 1] = p.laser_y + rv * s[beam]
    cum = np.cumsum(no_return)
    gap = np.zeros(len(beam), dtype=bool)
    if len(beam) > 1:
        # a no-return reading strictly between two consecutive valid beams
        gap[1:] = (cum[beam[1:] - 1] - cum[beam[:-1]]) > 0
    return ScanPoints(xy, beam, rv, (p.laser_x, p.laser_y), gap, float(scan.angle_increment))


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


def _ranges_index(s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenated indices s[i]..e[i] (inclusive) of every piece; their piece ids and run starts."""
    lengths = e - s + 1
    starts = np.cumsum(lengths) - lengths
    owner = np.repeat(np.arange(len(s)), lengths)
    idx = np.arange(len(owner)) + np.repeat(s - starts, lengths)
    return idx, owner, starts


def _split(xy: np.ndarray, s: np.ndarray, e: np.ndarray, thr: float) -> tuple[np.ndarray, np.ndarray]:
    """Iterative end-point fit of all pieces at once; returns the final (start, end) point indices."""
    done_s, done_e = [], []
    x, y = xy[:, 0], xy[:, 1]
    while len(s):
        inner = e - s >= 2
        if not inner.all():
            done_s.append(s[~inner])
            done_e.append(e[~inner])
            s, e = s[inner], e[inner]
            if not len(s):
                break
        idx, owner, starts = _ranges_index(s + 1, e - 1)
        ax, ay = x[s], y[s]
        abx, aby = x[e] - ax, y[e] - ay
        norm = np.maximum(np.hypot(abx, aby), 1e-9)
        d = np.abs(abx[owner] * (y[idx] - ay[owner]) - aby[owner] * (x[idx] - ax[owner])) / norm[owner]
        dmax = np.maximum.reduceat(d, starts)
        at_max = np.flatnonzero(d == dmax[owner])
        # owners are sorted, so the first maximum of each piece is found by a binary search
        m = idx[at_max[np.searchsorted(owner[at_max], np.arange(len(s)))]]
        split = dmax > thr
        if not split.all():
            done_s.append(s[~split])
            done_e.append(e[~split])
        s = np.concatenate([s[split], m[split]])
        e = np.concatenate([m[split], e[split]])
    s, e = np.concatenate(done_s), np.concatenate(done_e)
    order = np.argsort(s, kind="stable")
    return s[order], e[order]


def _fit(xy: np.ndarray, s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total least squares lines of the pieces: centroids (M, 2) and unit directions (M, 2)."""
    idx, owner, starts = _ranges_index(s, e)
    n = (e - s + 1).astype(float)
    p = xy[idx]
    c = np.add.reduceat(p, starts, axis=0) / n[:, None]
    q = p - c[owner]
    sxx = np.add.reduceat(q[:, 0] * q[:, 0], starts)
    syy = np.add.reduceat(q[:, 1] * q[:, 1], starts)
    sxy = np.add.reduceat(q[:, 0] * q[:, 1], starts)
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return c, np.stack([np.cos(phi), np.sin(phi)], axis=1)


def _snap_corners(seg: np.ndarray, cluster: np.ndarray, c: np.ndarray, u: np.ndarray, snap: float) -> None:
    """Join neighbouring pieces of one cluster at their lines' intersection when it is near both ends."""
    same = cluster[:-1] == cluster[1:]
    den = _cross(u[:-1], u[1:])
    ok = same & (np.abs(den) > math.sin(math.radians(20.0)))
    if not ok.any():
        return
    t = np.divide(_cross(c[1:] - c[:-1], u[1:]), den, out=np.zeros_like(den), where=ok)
    x = c[:-1] + t[:, None] * u[:-1]
    near = (np.hypot(*(x - seg[:-1, 1]).T) < snap) & (np.hypot(*(x - seg[1:, 0]).T) < snap)
    j = np.flatnonzero(ok & near)
    seg[j, 1] = x[j]
    seg[j + 1, 0] = x[j]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the 2-D cross products of rows (np.cross on 2-vectors is deprecated and slow)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _endpoints(xy: np.ndarray, s: np.ndarray, e: np.ndarray, c: np.ndarray, u: np.ndarray) -> np.ndarray:
    ta = np.einsum("ij,ij->i", xy[s] - c, u)
    tb = np.einsum("ij,ij->i", xy[e] - c, u)
    return np.stack([c + ta[:, None] * u, c + tb[:, None] * u], axis=1)


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
    seg = _endpoints(xy, s, e, c, u)
    if len(s) > 1:
        _snap_corners(seg, cluster, c, u, p.corner_snap)
    single = s == e
    if single.any():
        # a lone return (a leg): a short surface across its beam, centred on the point
        d = xy[s[single]] - np.asarray(pts.origin)
        t = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
        h = 0.5 * p.point_surface_length
        ctr = xy[s[single]]
        seg[single] = np.stack([ctr - h * t, ctr + h * t], axis=1)
    beams = np.stack([pts.beam[s], pts.beam[e]], axis=1)
    return Surfaces(seg, beams, np.stack([s, e], axis=1), cluster, pts)
