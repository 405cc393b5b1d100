"""Point-to-point ICP in one compiled call (:func:`icp`), for :meth:`mapper.localise.Localiser.refine`.

The whole loop (place the scan, pair each point with its nearest reference point within a gate,
the closed-form rigid motion of the pairs, compose, next gate) runs inside one kernel
(:mod:`mapper.jit`). Before, each step was a pykdtree query plus a few numpy calls from Python:
0.83 ms a refinement on the Intel raw replay (13 steps of about 170 points against about 1,600
reference points), 0.21 ms now, with the same pairs.

pykdtree cannot be called from numba, so the nearest-neighbour queries go to :class:`PointGrid`
instead. It answers the same question, the nearest point within a bound, exactly (0 of 45,000
queries differ from the kd-tree's for each of three cell sizes, ``tests/test_icp.py``): cells of
``cell`` metres hashed by their integer coordinates (a reference spans up to the laser's range, so a
dense array of cells could hold millions), searched ring by ring outwards from the query's cell
until no unseen cell can hold a nearer point or the bound is passed.

The kernels calling each other live in this one module on purpose: numba's disk cache checks only
the source file of the kernel it loads, so a kernel compiled with another module's kernel inlined
would keep running the old code after only that other module changed.
"""

from __future__ import annotations

import math

import numpy as np

from mapper.jit import kernel

_HASH_X = 73856093  # the usual spatial-hash primes (Teschner et al. 2003)
_HASH_Y = 19349663


class PointGrid:
    """Points (M, 2) (metres, the caller's frame) bucketed in square cells of ``cell`` m, for
    :func:`grid_nearest` inside compiled kernels. ``arrays`` is the tuple those kernels take."""

    __slots__ = ("arrays", "cell")

    def __init__(self, points: np.ndarray, cell: float) -> None:
        self.cell = float(cell)
        self.arrays = _grid_build(np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2), self.cell)


@kernel
def _grid_slot(ix: int, iy: int, mask: int) -> int:
    return ((ix * _HASH_X) ^ (iy * _HASH_Y)) & mask


@kernel
def _grid_build(points: np.ndarray, cell: float):
    """(points grouped by cell (M', 2), their original indices, and per hash slot: cell x, cell y,
    first and one-past-last grouped point (an empty slot has last = 0), the table's mask, and the
    cells' bounding box (x0, y0, x1, y1; empty: x0 > x1)). Points not finite are left out. Two
    passes over the points, no sort."""
    m = points.shape[0]
    inv = 1.0 / cell
    size = 4
    while size < 2 * m:
        size *= 2
    mask = size - 1
    tx = np.zeros(size, np.int64)
    ty = np.zeros(size, np.int64)
    t0 = np.zeros(size, np.int64)
    t1 = np.zeros(size, np.int64)
    slot = np.full(m, -1, np.int64)
    box = np.array([1, 1, 0, 0], np.int64)
    n = 0
    for i in range(m):  # find or make each point's cell; t1 counts its points for now
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])):
            continue
        ix = math.floor(points[i, 0] * inv)
        iy = math.floor(points[i, 1] * inv)
        if n == 0:
            box[0], box[1], box[2], box[3] = ix, iy, ix, iy
        else:
            box[0], box[1] = min(box[0], ix), min(box[1], iy)
            box[2], box[3] = max(box[2], ix), max(box[3], iy)
        n += 1
        h = _grid_slot(ix, iy, mask)
        while t1[h] != 0 and (tx[h] != ix or ty[h] != iy):
            h = (h + 1) & mask
        tx[h] = ix
        ty[h] = iy
        t1[h] += 1
        slot[i] = h
    start = 0
    for h in range(size):  # each cell's run of points
        c = t1[h]
        if c:
            t0[h] = start
            t1[h] = start
            start += c
    grouped = np.empty((n, 2))
    order = np.empty(n, np.int64)
    for i in range(m):
        h = slot[i]
        if h < 0:
            continue
        k = t1[h]
        t1[h] = k + 1
        grouped[k, 0] = points[i, 0]
        grouped[k, 1] = points[i, 1]
        order[k] = i
    return grouped, order, tx, ty, t0, t1, mask, box


@kernel(inline=True)
def grid_nearest(qx: float, qy: float, bound: float, cell: float, grid) -> tuple[int, float]:
    """The nearest grid point to (qx, qy) (m) closer than ``bound`` (m): (its original index,
    squared distance m²), or (-1, bound²) when none is. ``grid``: :attr:`PointGrid.arrays`. Exact:
    the point a kd-tree finds (up to ties). The query must be finite (:func:`icp` checks); the
    rings searched stop at the bound or once they hold every occupied cell. Inlined into the
    calling kernel (see :func:`mapper.jit.kernel`): 0.21 instead of 0.34 ms for an ICP of 13
    steps, 168 points. (Checks for a query not finite inside it cost 40 % more a query: they stay
    with the caller.)"""
    pts, order, tx, ty, t0, t1, mask, box = grid
    inv = 1.0 / cell
    fx, fy = qx * inv, qy * inv
    cx, cy = math.floor(fx), math.floor(fy)
    # m: how far the query is from its own cell's nearest edge; ring r's points are farther than
    # edge + (r - 1) cells
    edge = min(fx - cx, cx + 1 - fx, fy - cy, cy + 1 - fy) * cell
    best = bound * bound
    bi = -1
    # rings nearer than the box of occupied cells are empty: start at the first that reaches it
    r = max(0, box[0] - cx, cx - box[2], box[1] - cy, cy - box[3])
    while True:
        if r > 0:
            lb = edge + (r - 1) * cell
            if lb >= bound or lb * lb >= best:
                break
        for iy in range(cy - r, cy + r + 1):
            full = iy == cy - r or iy == cy + r
            step = 1 if full or r == 0 else 2 * r
            # m: how far the query is from this row of cells, then from each cell
            gy = max(iy * cell - qy, qy - (iy + 1) * cell, 0.0)
            if gy * gy >= best:
                continue
            for ix in range(cx - r, cx + r + 1, step):
                gx = max(ix * cell - qx, qx - (ix + 1) * cell, 0.0)
                if gx * gx + gy * gy >= best:
                    continue
                h = _grid_slot(ix, iy, mask)
                while t1[h] != 0:
                    if tx[h] == ix and ty[h] == iy:
                        for k in range(t0[h], t1[h]):
                            dx = pts[k, 0] - qx
                            dy = pts[k, 1] - qy
                            d2 = dx * dx + dy * dy
                            if d2 < best:
                                best = d2
                                bi = k
                        break
                    h = (h + 1) & mask
        if cx - r <= box[0] and cy - r <= box[1] and cx + r >= box[2] and cy + r >= box[3]:
            break  # every occupied cell has been searched (an infinite bound)
        r += 1
    if bi < 0:
        return -1, best
    return order[bi], best


@kernel
def rigid_motion(cur: np.ndarray, ref: np.ndarray, j: np.ndarray) -> tuple[int, float, float, float]:
    """One point-to-point ICP step: the rigid motion (rot, tx, ty: rad,
    m, m; the closed form of Arun et al.) that moves the points ``cur`` (K, 2, ASR frame) onto their
    nearest reference points ``ref[j]`` (M, 2), over the pairs with ``j`` >= 0 (-1: none within
    the gate), and the number of pairs (with fewer than 20, no motion). Compiled (:mod:`mapper.jit`):
    one call instead of about 15 numpy calls."""
    n = 0
    sax = say = sbx = sby = 0.0
    for i in range(j.shape[0]):
        k = j[i]
        if k >= 0:
            n += 1
            sax += cur[i, 0]
            say += cur[i, 1]
            sbx += ref[k, 0]
            sby += ref[k, 1]
    if n < 20:
        return n, 0.0, 0.0, 0.0
    max_, may, mbx, mby = sax / n, say / n, sbx / n, sby / n
    h00 = h01 = h10 = h11 = 0.0
    for i in range(j.shape[0]):
        k = j[i]
        if k >= 0:
            ax, ay = cur[i, 0] - max_, cur[i, 1] - may
            bx, by = ref[k, 0] - mbx, ref[k, 1] - mby
            h00 += ax * bx
            h01 += ax * by
            h10 += ay * bx
            h11 += ay * by
    rot = math.atan2(h01 - h10, h00 + h11)
    c, s = math.cos(rot), math.sin(rot)
    return n, rot, mbx - (c * max_ - s * may), mby - (s * max_ + c * may)


@kernel
def _wrap(theta: float) -> float:
    """:func:`mapper.se2.wrap` (radians to (-pi, pi]) inside kernels: numba has no ``math.fmod``,
    and ``np.fmod`` is the same C function."""
    t = np.fmod(theta + math.pi, 2.0 * math.pi)
    if t <= 0.0:
        t += 2.0 * math.pi
    return t - math.pi


@kernel(inline=True)
def _place(xy: np.ndarray, x: float, y: float, th: float, out: np.ndarray) -> None:
    """The points ``xy`` (K, 2, robot frame) placed at (x, y, th) (m, m, rad), written to ``out``."""
    c, s = math.cos(th), math.sin(th)
    for i in range(xy.shape[0]):
        out[i, 0] = x + c * xy[i, 0] - s * xy[i, 1]
        out[i, 1] = y + s * xy[i, 0] + c * xy[i, 1]


@kernel
def icp(xy: np.ndarray, ref: np.ndarray, x: float, y: float, th: float, gates: np.ndarray, inlier: float,
         cell: float, grid) -> tuple[int, float, float, float, np.ndarray, np.ndarray]:
    """ICP of :meth:`Localiser.refine` in one compiled call. The scan points ``xy`` (K, 2, robot
    frame) are placed at (x, y, th) (ASR frame: m, m, rad); then, for each gate (m) in turn, each
    point is paired with its nearest reference point (``ref`` (M, 2), ASR frame) within the gate
    (``grid``: the arrays of a :class:`PointGrid` over ``ref``, cells of ``cell``
    m), and the :func:`rigid_motion` of the pairs is composed onto the pose. Returns (pairs at the
    last step, fewer than 20 stopping early; x, y, th; the points at that pose (K, 2); each
    point's nearest reference point within ``inlier`` m, -1 for none). No reference, or a pose or
    a point not finite, gives 0 pairs and no motion."""
    k = xy.shape[0]
    m = ref.shape[0]
    cur = np.empty((k, 2))
    j = np.full(k, -1, np.int64)
    finite = m > 0 and math.isfinite(x) and math.isfinite(y) and math.isfinite(th)
    for i in range(k):
        finite = finite and math.isfinite(xy[i, 0]) and math.isfinite(xy[i, 1])
    if not finite:  # no reference, or a pose or point not finite (the grid needs finite queries)
        cur[:] = np.nan
        return 0, x, y, th, cur, j
    _place(xy, x, y, th, cur)
    n = 0
    for gate in gates:
        for i in range(k):
            j[i], _ = grid_nearest(cur[i, 0], cur[i, 1], gate, cell, grid)
        n, rot, tx, ty = rigid_motion(cur, ref, j)
        if n < 20:
            return n, x, y, th, cur, j
        cr, sr = math.cos(rot), math.sin(rot)
        x, y, th = tx + cr * x - sr * y, ty + sr * x + cr * y, _wrap(rot + th)
        _place(xy, x, y, th, cur)
    for i in range(k):
        j[i], _ = grid_nearest(cur[i, 0], cur[i, 1], inlier, cell, grid)
    return n, x, y, th, cur, j
