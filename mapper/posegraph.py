"""An ASR-level SE(2) pose graph relaxed by Gauss-Newton (method.md §7, realignment).

Nodes are ASR frames' global poses x_i = (x, y, theta) (m, m, rad). An edge (i, j, z, Ω) says "frame j
seen from frame i is z" with information matrix Ω (inverse covariance, units 1/m² and 1/rad²).
Following Grisetti et al., "A tutorial on graph-based SLAM" (2010), the error of an edge is

    e = [ R_z^T (R_i^T (t_j - t_i) - t_z) ;  wrap(θ_j - θ_i - θ_z) ]

with Jacobians

    A = ∂e/∂x_i = [[-R_z^T R_i^T,  R_z^T dR_i^T/dθ_i (t_j - t_i)], [0, 0, -1]]
    B = ∂e/∂x_j = [[ R_z^T R_i^T,  0], [0, 0, 1]]

Each iteration solves the sparse normal equations H Δx = -b (H = Σ JᵀΩJ, b = Σ JᵀΩe) with one
node held fixed (the gauge), then x ← x + Δx. The system is block-sparse: 3x3 blocks on the
diagonal and one block pair per edge; scipy.sparse solves it in O(N) for a chain with few loops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mapper.se2 import Pose, wrap_array


@dataclass(frozen=True, slots=True)
class Edge:
    """Constraint: node ``j``'s frame seen from node ``i``'s frame is ``z`` (m, m, rad); ``info`` 3x3."""

    i: int
    j: int
    z: Pose
    info: np.ndarray


@dataclass(frozen=True, slots=True)
class Result:
    """Relaxed poses (id -> pose), iterations run, χ² (Σ eᵀΩe) before and after."""

    poses: dict[int, Pose]
    iterations: int
    chi2_before: float
    chi2_after: float


def diagonal_info(sigma_xy: float, sigma_theta: float) -> np.ndarray:
    """Information matrix of independent x, y (std ``sigma_xy`` m) and theta (``sigma_theta`` rad)."""
    return np.diag([1.0 / sigma_xy**2, 1.0 / sigma_xy**2, 1.0 / sigma_theta**2])


def _rot(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def errors_and_jacobians(xi: np.ndarray, xj: np.ndarray, z: np.ndarray):
    """Errors (M, 3) and Jacobians A, B (M, 3, 3) of M edges; xi, xj, z arrays (M, 3)."""
    xi, xj, z = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (xi, xj, z))
    ri, rz = _rot(xi[:, 2]), _rot(z[:, 2])
    ri_t, rz_t = np.swapaxes(ri, -1, -2), np.swapaxes(rz, -1, -2)
    dt = xj[:, :2] - xi[:, :2]
    local = np.einsum("mab,mb->ma", ri_t, dt)
    e = np.empty_like(xi)
    e[:, :2] = np.einsum("mab,mb->ma", rz_t, local - z[:, :2])
    e[:, 2] = wrap_array(xj[:, 2] - xi[:, 2] - z[:, 2])
    c, s = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    # d(R_i^T)/dθ_i = [[-s, c], [-c, -s]]
    dri_t = np.stack([np.stack([-s, c], -1), np.stack([-c, -s], -1)], -2)
    rzri = np.einsum("mab,mbc->mac", rz_t, ri_t)
    m = len(xi)
    a = np.zeros((m, 3, 3))
    b = np.zeros((m, 3, 3))
    a[:, :2, :2] = -rzri
    a[:, :2, 2] = np.einsum("mab,mbc,mc->ma", rz_t, dri_t, dt)
    a[:, 2, 2] = -1.0
    b[:, :2, :2] = rzri
    b[:, 2, 2] = 1.0
    return e, a, b


def chi2(poses: dict[int, Pose], edges: list[Edge]) -> float:
    """Σ eᵀΩe over the edges (dimensionless)."""
    if not edges:
        return 0.0
    xi = np.array([poses[e.i] for e in edges])
    xj = np.array([poses[e.j] for e in edges])
    z = np.array([e.z for e in edges])
    err, _, _ = errors_and_jacobians(xi, xj, z)
    info = np.stack([e.info for e in edges])
    return float(np.einsum("ma,mab,mb->", err, info, err))


def optimise(
    poses: dict[int, Pose],
    edges: list[Edge],
    fixed: int | None = None,
    iterations: int = 20,
    tol: float = 1e-6,
) -> Result:
    """Gauss-Newton on the graph; ``fixed`` (default: the smallest id) stays where it is.

    Stops when the largest update is below ``tol`` (m or rad) or after ``iterations``.
    Nodes without edges keep their poses.
    """
    ids = sorted(poses)
    if fixed is None:
        fixed = ids[0]
    col = {k: n for n, k in enumerate(ids)}
    x = np.array([poses[k] for k in ids], dtype=float)
    before = chi2(poses, edges)
    if not edges:
        return Result(dict(poses), 0, before, before)
    ii = np.array([col[e.i] for e in edges])
    jj = np.array([col[e.j] for e in edges])
    z = np.array([e.z for e in edges], dtype=float)
    info = np.stack([e.info for e in edges])
    n = len(ids)
    free = np.ones(3 * n, dtype=bool)
    free[3 * col[fixed] : 3 * col[fixed] + 3] = False
    # Nodes no edge touches would make H singular: hold them too.
    touched = np.zeros(n, dtype=bool)
    touched[ii] = touched[jj] = True
    free &= np.repeat(touched, 3)
    done = 0
    while done < iterations:
        done += 1
        h, g = _normal_equations(x, ii, jj, z, info)
        hf = h[free][:, free].tocsc()
        dx = np.zeros(3 * n)
        dx[free] = spla.spsolve(hf, -g[free])
        x += dx.reshape(n, 3)
        x[:, 2] = wrap_array(x[:, 2])
        if np.max(np.abs(dx)) < tol:
            break
    out = {k: (float(x[c, 0]), float(x[c, 1]), float(x[c, 2])) for k, c in col.items()}
    return Result(out, done, before, chi2(out, edges))


def _normal_equations(x: np.ndarray, ii: np.ndarray, jj: np.ndarray, z: np.ndarray, info: np.ndarray):
    """H = Σ JᵀΩJ (sparse, 3N x 3N) and b = Σ JᵀΩe at the poses ``x`` (N, 3); edge m joins rows
    ``ii[m]`` and ``jj[m]`` of ``x`` with measurement ``z[m]`` and information ``info[m]``."""
    n = len(x)
    err, a, b = errors_and_jacobians(x[ii], x[jj], z)
    blocks = [
        (ii, ii, np.einsum("mka,mkl,mlb->mab", a, info, a)),
        (ii, jj, np.einsum("mka,mkl,mlb->mab", a, info, b)),
        (jj, ii, np.einsum("mka,mkl,mlb->mab", b, info, a)),
        (jj, jj, np.einsum("mka,mkl,mlb->mab", b, info, b)),
    ]
    rows, cols, vals = [], [], []
    r3 = np.arange(3)
    for p, q, blk in blocks:
        rows.append((3 * p[:, None, None] + r3[None, :, None]).repeat(3, axis=2).ravel())
        cols.append((3 * q[:, None, None] + r3[None, None, :]).repeat(3, axis=1).ravel())
        vals.append(blk.ravel())
    h = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n)
    )
    g = np.zeros(3 * n)
    np.add.at(g, (3 * ii[:, None] + r3).ravel(), np.einsum("mka,mkl,ml->ma", a, info, err).ravel())
    np.add.at(g, (3 * jj[:, None] + r3).ravel(), np.einsum("mka,mkl,ml->ma", b, info, err).ravel())
    return h, g


def relative_covariance(poses: dict[int, Pose], edges: list[Edge], i: int, j: int) -> np.ndarray | None:
    """Covariance (3x3: m², m·rad, rad²; global axes) of node ``j``'s pose with node ``i`` held
    fixed: how far the graph's edges, linearised at ``poses``, let ``j`` be off relative to ``i``.
    Along a chain it is the sum of the edges' covariances carried along it; every loop the graph
    closes between them tightens it. None when no chain of edges joins them."""
    if i not in poses or j not in poses or i == j:
        return None
    adj: dict[int, set[int]] = {}
    for e in edges:
        adj.setdefault(e.i, set()).add(e.j)
        adj.setdefault(e.j, set()).add(e.i)
    joined, frontier = {i}, [i]  # the nodes a chain of edges joins to i (the rest would be singular)
    while frontier:
        for b in adj.get(frontier.pop(), ()):
            if b not in joined:
                joined.add(b)
                frontier.append(b)
    if j not in joined:
        return None
    ids = sorted(joined)
    col = {k: c for c, k in enumerate(ids)}
    inside = [e for e in edges if e.i in joined]
    x = np.array([poses[k] for k in ids], dtype=float)
    ii = np.array([col[e.i] for e in inside])
    jj = np.array([col[e.j] for e in inside])
    h, _ = _normal_equations(x, ii, jj, np.array([e.z for e in inside], dtype=float),
                             np.stack([e.info for e in inside]))
    free = np.ones(3 * len(ids), dtype=bool)
    free[3 * col[i] : 3 * col[i] + 3] = False
    at = np.flatnonzero(free)
    rows = np.searchsorted(at, 3 * col[j] + np.arange(3))
    rhs = np.zeros((len(at), 3))
    rhs[rows, np.arange(3)] = 1.0
    sol = spla.spsolve(h[free][:, free].tocsc(), rhs)
    cov = np.asarray(sol)[rows]
    if not np.all(np.isfinite(cov)):
        return None
    return 0.5 * (cov + cov.T)
