"""Where an exit is crossed (ASR frame, m): on its chord's normal, or between the arms of a U of exit
edges (a corridor's end seen from inside); how deep the free space beyond it reaches; and the straight
pieces of an exit's run taken as exits of their own (side openings)."""

from __future__ import annotations

import itertools

import numpy as np
import shapely

from mapper.se2 import wrap_array
from mapper.types import ASR, Exit
from service.explore.params import ExploreParams
from service.explore.regions import outward


def exit_run(asr: ASR, ex: Exit) -> np.ndarray | None:
    """The boundary vertex indices (K,) of the run of exit edges whose chord ``ex`` is (from ``a`` to
    ``b`` along the boundary), or None (not the ASR's own exit, or the run is not all exit edges)."""
    b = np.asarray(asr.boundary, dtype=float)
    n = len(b)
    if n < 3 or len(asr.edges) != n:
        return None
    da = np.hypot(*(b - np.asarray(ex.a, dtype=float)).T)
    db = np.hypot(*(b - np.asarray(ex.b, dtype=float)).T)
    ia, ib = int(np.argmin(da)), int(np.argmin(db))
    if da[ia] > 1e-6 or db[ib] > 1e-6 or ia == ib:
        return None
    idx = [ia]
    while idx[-1] != ib:
        if asr.edges[idx[-1]] != "exit" or len(idx) > n:
            return None
        idx.append((idx[-1] + 1) % n)
    return np.array(idx)


def _surface_line(asr: ASR, vertex: int, step: int, length: float = 0.5,
                  skip: float = 0.15) -> tuple[np.ndarray, np.ndarray] | None:
    """The line (point, unit direction pointing towards ``vertex``) of the surface edges next to
    boundary vertex ``vertex``, walking ``step`` (-1: back, +1: on) over up to ``length`` m of them
    (after at most ``skip`` m of other edges: a sliver of ``unknown`` between a wall and its grazing
    continuation); None when they are shorter than 0.3 m together (too short to give a direction)."""
    b = np.asarray(asr.boundary, dtype=float)
    n = len(b)
    k, start, far = vertex, None, 0.0
    for _ in range(n):
        edge = (k - 1) % n if step < 0 else k  # the edge between k and its neighbour that way
        k2 = (k + step) % n
        if asr.edges[edge] != "surface":
            if start is not None or float(np.hypot(*(b[k2] - b[vertex]))) > skip:
                break
            k = k2
            continue
        if start is None:
            start = k
        far = float(np.hypot(*(b[k2] - b[start])))
        k = k2
        if far >= length:
            break
    if start is None or far < 0.3:
        return None
    d = b[start] - b[k]
    return b[start], d / float(np.hypot(*d))


def _grazing(pts: np.ndarray, line: tuple[np.ndarray, np.ndarray] | None, tol: float) -> int:
    """How many leading edges of the polyline ``pts`` run on along ``line`` (every vertex within
    ``tol`` m of it, each one no farther back along it than the one before)."""
    if line is None:
        return 0
    q, u = line
    rel = pts - q
    off = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
    along = rel @ u
    k = 0
    while k + 1 < len(pts) and off[k + 1] < tol and along[k + 1] > along[k] - 0.05:
        k += 1
    return k


def crossing(asr: ASR, ex: Exit, p: ExploreParams) -> tuple[np.ndarray, np.ndarray]:
    """Where to cross exit ``ex`` of ``asr``: (staging point inside, point beyond), ASR frame.

    Normally on the exit chord's normal, ``stage_distance`` inside and ``through_distance`` beyond
    the polygon. But a run of exit edges often begins or ends with a wall seen at a grazing angle
    (its scan returns too sparse for a surface fit), which runs on along the line of the surface
    next to it: a corridor seen from inside ends in a U of exit edges, two walls and the open end
    across. Its chord runs diagonally across the corridor, and the chord's normal leads into a wall
    or out of the world, or to the far corner of the U, still inside the polygon. The arms that
    continue the line of the surface beside them are cut off, and the crossing is made through
    what is left (the open end), on its own normal.
    """
    a, b = np.asarray(ex.a, dtype=float), np.asarray(ex.b, dtype=float)
    idx = exit_run(asr, ex)
    if idx is not None and len(idx) > 2:
        run = np.asarray(asr.boundary, dtype=float)[idx]
        ia, ib = int(idx[0]), int(idx[-1])
        tol = p.grazing_offset
        lead = _grazing(run, _surface_line(asr, ia, -1), tol)
        back = _grazing(run[::-1], _surface_line(asr, ib, +1), tol)
        rest = run[lead: len(run) - back]
        if lead + back > 0 and len(rest) >= 2 and float(np.hypot(*(rest[-1] - rest[0]))) >= p.min_opening:
            a, b = rest[0], rest[-1]
    n = outward(asr, a, b)
    mid = (a + b) / 2.0
    depth = depth_beyond(asr, mid, n)
    return mid - p.stage_distance * n, mid + (depth + p.through_distance) * n


def depth_beyond(asr: ASR, mid: np.ndarray, n: np.ndarray, reach: float = 2.0) -> float:
    """How far (m, at most ``reach``) from ``mid`` along ``n`` the ray leaves the ASR polygon: 0 for
    an exit on the boundary. An exit is the chord of a run of exit edges, and a run that bends
    (pieced together from several views) leaves polygon beyond the chord: the mapper sees the
    robot leave only once it is outside the polygon."""
    poly = shapely.make_valid(asr.polygon)
    probe = mid + np.outer(np.arange(0.05, reach + 1e-9, 0.05), n)
    inside = shapely.contains_xy(poly, probe[:, 0], probe[:, 1])
    if not inside.any():
        return 0.0
    last = int(np.flatnonzero(inside)[-1])
    return float(min(reach, 0.05 * (last + 1)))


SIDE = "~"  # in a side opening's id: its exit's id + "~" + the piece's midpoint (ASR frame, cm)


def side_openings(asr: ASR, ex: Exit, p: ExploreParams) -> list[Exit]:
    """The straight pieces of ``ex``'s run of exit edges (ASR frame, m) that could be doorways of
    their own (``ExploreParams.side_openings``): the run cut where it turns more than
    ``side_turn``; the pieces at least ``min_exit_width`` long, when there are two or more pieces.
    Each is an :class:`Exit` with no link, its id ``ex.id`` + ``SIDE`` + its midpoint (ASR frame,
    whole cm): the same piece keeps its id while views move its ends a little (:func:`exit_of`).
    A piece along a wall seen at a grazing angle (a corridor's U of exit edges) is one too: the
    scan shows it shut (:meth:`Planner.shut_exits`) or the way through blocked, as for any exit
    into a wall."""
    idx = exit_run(asr, ex)
    if idx is None or len(idx) < 3:
        return []
    pts = np.asarray(asr.boundary, dtype=float)[idx]
    d = np.diff(pts, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs(wrap_array(np.diff(heading)))
    cuts = np.flatnonzero(turn > p.side_turn) + 1  # vertices (of pts) where a piece ends
    if not len(cuts):
        return []
    bounds = [0, *cuts.tolist(), len(pts) - 1]
    out = []
    for i, j in itertools.pairwise(bounds):
        a, b = pts[i], pts[j]
        if float(np.hypot(*(b - a))) >= p.min_exit_width:
            m = np.round(50.0 * (a + b)).astype(int)
            out.append(Exit(f"{ex.id}{SIDE}{m[0]},{m[1]}", (float(a[0]), float(a[1])),
                            (float(b[0]), float(b[1]))))
    return out
