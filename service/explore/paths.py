"""Grid paths inside an ASR's polygon (one frame, m): 8-neighbour shortest paths keeping a clearance
from the polygon's edge and from obstacle points."""

from __future__ import annotations

import math

import numpy as np
import shapely


def plan_path(polygon: shapely.Geometry, start: tuple[float, float], goal: tuple[float, float],
              cell: float, clearance: float, obstacles: np.ndarray | None = None) -> np.ndarray | None:
    """Shortest path (K, 2) from ``start`` to ``goal`` through ``polygon`` shrunk by ``clearance``
    (m, one frame), on a grid of ``cell`` m with 8 neighbours, keeping ``clearance`` from each of
    ``obstacles`` (M, 2) too; its first and last points are the free cells nearest ``start`` and
    ``goal`` (each within 4 cells of free space, else None)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    free = shapely.make_valid(polygon).buffer(-clearance)
    if free.is_empty:
        return None
    x0, y0, x1, y1 = free.bounds
    nx, ny = int((x1 - x0) / cell) + 2, int((y1 - y0) / cell) + 2
    if nx * ny > 400_000:
        return None
    xs, ys = x0 + cell * np.arange(nx), y0 + cell * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    ok = shapely.contains_xy(free, gx, gy)
    if obstacles is not None and len(obstacles):
        _clear_around(ok, (x0, y0), cell, np.asarray(obstacles, dtype=float), clearance)
    if not ok.any():
        return None
    idx = -np.ones((nx, ny), dtype=int)
    idx[ok] = np.arange(int(ok.sum()))
    pts = np.column_stack([gx[ok], gy[ok]])

    def nearest(q: tuple[float, float]) -> int | None:
        d = np.hypot(pts[:, 0] - q[0], pts[:, 1] - q[1])
        k = int(np.argmin(d))
        return k if d[k] <= 4.0 * cell else None

    a, b = nearest(start), nearest(goal)
    if a is None or b is None:
        return None
    rows, cols, w = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        src = idx[max(0, -di): nx - max(0, di), max(0, -dj): ny - max(0, dj)]
        dst = idx[max(0, di): nx - max(0, -di) or None, max(0, dj): ny - max(0, -dj) or None]
        m = (src >= 0) & (dst >= 0)
        rows.append(src[m])
        cols.append(dst[m])
        w.append(np.full(int(m.sum()), cell * math.hypot(di, dj)))
    n = len(pts)
    graph = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    dist, pred = dijkstra(graph.tocsr(), directed=False, indices=a, return_predecessors=True)
    if not np.isfinite(dist[b]):
        return None
    path = [b]
    while path[-1] != a:
        path.append(int(pred[path[-1]]))
    return pts[path[::-1]]


def _clear_around(ok: np.ndarray, origin: tuple[float, float], cell: float, points: np.ndarray,
                  radius: float) -> None:
    """Mark not free (in place) the cells of the grid ``ok`` (cell (i, j) at origin + cell * (i, j),
    m) within ``radius`` m of any of ``points`` (M, 2)."""
    k = math.ceil(radius / cell)
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    ci = np.rint((points[:, 0] - origin[0]) / cell).astype(int)
    cj = np.rint((points[:, 1] - origin[1]) / cell).astype(int)
    ii, jj = ci[:, None] + di.ravel()[None, :], cj[:, None] + dj.ravel()[None, :]
    dx = origin[0] + cell * ii - points[:, 0:1]
    dy = origin[1] + cell * jj - points[:, 1:2]
    hit = (np.hypot(dx, dy) < radius) & (ii >= 0) & (ii < ok.shape[0]) & (jj >= 0) & (jj < ok.shape[1])
    ok[ii[hit], jj[hit]] = False
