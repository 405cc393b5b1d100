"""Occlusions and exits of one view (method.md §2.1-2.2), robot frame, metres.

Surfaces come in angular order (:class:`mapper.lines.Surfaces`). Between two consecutive surfaces
of different breakpoint clusters lies a *gap*:

* **no-return gap** (a no-return reading lies between them): covered by the segment joining the two
  surfaces' ends;
* **depth discontinuity**: the occluding end P is the nearer of the two ends (distance from the
  laser); the gap opens on the side of P away from its own surface. Every surface angularly across
  the gap (all surfaces beyond P in sweep order, near or far) offers its closest point Q to P
  (closest point on the segment, not only endpoints); a candidate P->Q is *visible* when every
  surface angularly between P and Q lies beyond the line PQ as seen from the laser (so PQ crosses no
  surface and hides nothing nearer). The shortest visible candidate covers the occlusion.

A covering segment at least ``passage_width`` long is an **exit**; a shorter one **closes** the gap
(chair legs, table legs): the view's boundary follows it and it is labelled ``surface``. A gap with
no visible candidate stays open and is labelled ``unknown``.

Each covering segment spans an interval of the sweep (from P's position to Q's, positions ``2k + t``
for the point at fraction t along surface k). Where intervals nest, the outer one wins: it is nearer
the robot and what lies inside it was seen *through* it (the second room behind a doorway). The two
covers of one doorway (found from each jamb) span the same interval and become one exit.
Every gap's candidates are evaluated in one compiled loop (:mod:`mapper.jit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mapper.jit import kernel
from mapper.lines import Surfaces
from mapper.params import MapperParams

#: Labels of a gap's cover: an exit, a closed gap (labelled ``surface`` on the boundary), or open.
EXIT, CLOSED, OPEN = "exit", "surface", "unknown"
_CANDIDATES = 6  # shortest candidates per gap checked for visibility
_WINDOW = 32  # surfaces across a gap considered for its cover (a doorway seen past clutter is < 32)
_ALT_SLACK = 0.05  # m: a jamb's side is a few beams, its fit is off by a few cm
_JAMB_MAX = 0.5  # m: the deepest wall whose jamb side counts as part of a doorway


@dataclass(frozen=True, slots=True, eq=False)
class Covers:
    """The selected covers of one view's gaps, in sweep order (robot frame, m).

    ``a``, ``b`` (N, 2): the cover's clockwise and counter-clockwise ends; ``label`` (N,) one of
    ``exit``/``surface``/``unknown``; ``lo``, ``hi`` (N,): the sweep positions of a and b (see module
    docstring); ``occluding`` (N,) which end is the occluding end P (0: a, 1: b; -1 for no-return gaps).
    ``through_robot``: how many exits were left out because they ran through the robot (it stands
    in that gap, see :func:`find_covers`).
    """

    a: np.ndarray
    b: np.ndarray
    label: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    occluding: np.ndarray
    through_robot: int = 0

    def __len__(self) -> int:
        return len(self.a)

    @property
    def exits(self) -> np.ndarray:
        """Exit segments (E, 2, 2), robot frame (m)."""
        m = self.label == EXIT
        return np.stack([self.a[m], self.b[m]], axis=1)


def closest_on_segments(p: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on segments to points, broadcast: ``p`` (..., 2), ``seg`` (..., 2, 2).

    Returns the points (..., 2) and their fractions t in [0, 1] along each segment.
    """
    qx, qy, t = closest_xy(p[..., 0], p[..., 1], seg)
    return np.stack((qx, qy), axis=-1), t


def closest_xy(px: np.ndarray, py: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`closest_on_segments` by components: points (px, py) (...), segments (..., 2, 2);
    the closest points' x and y and the fractions t along the segments."""
    ax, ay = seg[..., 0, 0], seg[..., 0, 1]
    abx, aby = seg[..., 1, 0] - ax, seg[..., 1, 1] - ay
    den = np.maximum(abx * abx + aby * aby, 1e-18)
    t = np.clip(((px - ax) * abx + (py - ay) * aby) / den, 0.0, 1.0)
    return ax + t * abx, ay + t * aby, t


@kernel
def closest_point(
    px: float, py: float, ax: float, ay: float, abx: float, aby: float
) -> tuple[float, float, float]:
    """:func:`closest_xy` for one point (px, py) and one segment from (ax, ay) along (abx, aby), for
    compiled loops (m, one frame): the closest point's x and y and its fraction t along the segment."""
    t = min(max(((px - ax) * abx + (py - ay) * aby) / max(abx * abx + aby * aby, 1e-18), 0.0), 1.0)
    return ax + t * abx, ay + t * aby, t


def segment_distance(px: np.ndarray, py: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance (m) from points (px, py) (...) to segments (..., 2, 2), all in one frame."""
    qx, qy, _ = closest_xy(px, py, seg)
    return np.hypot(qx - px, qy - py)


@kernel
def _shortest(
    seg: np.ndarray, o: np.ndarray, pp: np.ndarray, gap: np.ndarray, right: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each gap, the shortest visible segment from its occluding point ``pp`` across the gap
    (robot frame, m; the laser at ``o``).

    The surfaces across gap g are those after ``gap[g]`` in sweep order when ``right[g]``, else
    from ``gap[g]`` backwards: a window of ``_WINDOW`` of them, nearest first, since a cover lands
    within a few surfaces of its gap. Each offers its closest point Q to P. Only the
    ``_CANDIDATES`` shortest are tried (a longer one would be taken only when all of these are
    hidden, and then the gap is wide open anyway), shortest first; equal lengths (a corner two
    surfaces share) nearest in the window first, so the cover ends on the nearer surface's end. A
    candidate is visible when both ends of every surface between P and Q in the window lie beyond
    the line PQ as seen from the laser (by more than ``tol``, m). Returns the
    surface index it lands on, its length (inf: none visible), the point Q and its fraction along
    that surface. Compiled (:mod:`mapper.jit`): each gap's few candidates are tried in turn
    without broadcasting all of them."""
    m = seg.shape[0]
    g_n = gap.shape[0]
    w = min(_WINDOW, m)
    nc = min(_CANDIDATES, w)
    best = np.zeros(g_n, dtype=np.int64)
    best_len = np.full(g_n, np.inf)
    qb = np.zeros((g_n, 2))
    tqb = np.zeros(g_n)
    kw = np.empty(w, dtype=np.int64)
    length = np.empty(w)
    qx, qy, tq = np.empty(w), np.empty(w), np.empty(w)
    for g in range(g_n):
        px, py = pp[g, 0], pp[g, 1]
        for j in range(w):
            k = gap[g] + 1 + j if right[g] else gap[g] - j
            kw[j] = k
            if k < 0 or k >= m:
                length[j] = np.inf
                continue
            ax, ay = seg[k, 0, 0], seg[k, 0, 1]
            qx[j], qy[j], tq[j] = closest_point(px, py, ax, ay, seg[k, 1, 0] - ax, seg[k, 1, 1] - ay)
            length[j] = math.hypot(qx[j] - px, qy[j] - py)
        order = np.argsort(length, kind="mergesort")  # stable: equal lengths nearest first
        for r in range(nc):
            c = order[r]
            if not length[c] < np.inf:
                break
            dx, dy = qx[c] - px, qy[c] - py
            dn = max(math.hypot(dx, dy), 1e-9)
            sgn = 1.0 if dx * (o[1] - py) - dy * (o[0] - px) >= 0 else -1.0  # the laser's side of PQ
            hidden = False
            for j in range(c):
                k = kw[j]
                if 0 <= k < m:
                    for end in range(2):
                        ex, ey = seg[k, end, 0] - px, seg[k, end, 1] - py
                        if (dx * ey - dy * ex) / dn * sgn > tol:
                            hidden = True
                if hidden:
                    break
            if not hidden:
                best[g], best_len[g] = kw[c], length[c]
                qb[g, 0], qb[g, 1], tqb[g] = qx[c], qy[c], tq[c]
                break
    return best, best_len, qb, tqb


_LABELS = np.array([EXIT, CLOSED, OPEN], dtype=object)  # by the codes :func:`_covers` returns


def find_covers(surf: Surfaces, p: MapperParams) -> Covers:
    """Covers of every gap of one view; see the module docstring (the work: :func:`_covers`)."""
    seg = surf.segments
    if len(seg) < 2:
        empty = np.zeros((0, 2))
        z = np.zeros(0)
        return Covers(empty, empty, np.zeros(0, dtype=object), z, z, np.zeros(0, dtype=int))
    a, b, code, lo, hi, occl, through = _covers(
        seg, surf.cluster, surf.pidx, surf.points.gap_no_return, float(surf.points.origin[0]),
        float(surf.points.origin[1]), p.visibility_tolerance, p.passage_width, p.rear_closure,
    )
    return Covers(a, b, _LABELS[code], lo, hi, occl, int(through))


@kernel
def _covers(
    seg: np.ndarray, cluster: np.ndarray, pidx: np.ndarray, gap_no_return: np.ndarray, ox: float,
    oy: float, tol: float, passage_width: float, rear_closure: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """:func:`find_covers`' work on one view's surfaces ``seg`` (M >= 2, robot frame, m; the laser
    at (ox, oy)), compiled (:mod:`mapper.jit`). Replaces the numpy form, per gap g between surfaces
    ``gap[g]`` and ``gap[g] + 1`` (``flatnonzero(cluster[:-1] != cluster[1:])``)::

        right = hypot(*(end_j - o).T) <= hypot(*(start_n - o).T)   # P = end of j, opening CCW
        pp = where(right, end_j, start_n); alt = the jamb side's other end
        near = flatnonzero(hypot(*(alt - pp).T) <= _JAMB_MAX)
        _shortest(seg, o, concatenate([pp, alt[near]]), ...)        # both ends' searches, one call
        # the jamb's cover taken where no more than _ALT_SLACK longer and its midpoint nearer o
        label = where(best_len >= passage_width, EXIT, CLOSED); OPEN where none visible
        a, b = where(right, (pp, qb), (qb, pp)); lo, hi = sweep positions (module docstring)
        # open and no-return gaps: the segment joining the surfaces' ends (no-return: EXIT when
        # at least passage_width long); exits within rear_closure (m) of the robot left out
        # the outermost of nested covers: in lexsort((-hi, lo)) order, each kept unless it starts
        # before the last kept one ends (identical or crossing covers dropped)

    Returns the kept covers' a, b (N, 2), label codes (N,) (0 exit, 1 surface, 2 unknown;
    ``_LABELS``), sweep positions lo, hi (N,), occluding end (N,) (0 a, 1 b, -1 no-return) and how
    many exits ran through the robot. hypot is libm's, as numpy's ``np.hypot``."""
    gap = np.flatnonzero(cluster[:-1] != cluster[1:])
    ng = len(gap)
    right = np.empty(ng, dtype=np.bool_)
    no_ret = np.empty(ng, dtype=np.bool_)
    pp = np.empty((ng, 2))
    alt = np.empty((ng, 2))
    n_near = 0
    near_of = np.empty(ng, dtype=np.int64)  # which gap each jamb search belongs to
    for g in range(ng):
        j = gap[g]
        no_ret[g] = gap_no_return[pidx[j + 1, 0]]
        right[g] = (np.hypot(seg[j, 1, 0] - ox, seg[j, 1, 1] - oy)
                    <= np.hypot(seg[j + 1, 0, 0] - ox, seg[j + 1, 0, 1] - oy))
        if right[g]:
            pp[g, 0], pp[g, 1] = seg[j, 1, 0], seg[j, 1, 1]
            alt[g, 0], alt[g, 1] = seg[j, 0, 0], seg[j, 0, 1]
        else:
            pp[g, 0], pp[g, 1] = seg[j + 1, 0, 0], seg[j + 1, 0, 1]
            alt[g, 0], alt[g, 1] = seg[j + 1, 1, 0], seg[j + 1, 1, 1]
        if np.hypot(alt[g, 0] - pp[g, 0], alt[g, 1] - pp[g, 1]) <= _JAMB_MAX:
            near_of[n_near] = g
            n_near += 1
    n_all = ng + n_near
    pp2 = np.empty((n_all, 2))
    gap2 = np.empty(n_all, dtype=np.int64)
    right2 = np.empty(n_all, dtype=np.bool_)
    for g in range(ng):
        pp2[g, 0], pp2[g, 1], gap2[g], right2[g] = pp[g, 0], pp[g, 1], gap[g], right[g]
    for r in range(n_near):
        g = near_of[r]
        pp2[ng + r, 0], pp2[ng + r, 1], gap2[ng + r], right2[ng + r] = alt[g, 0], alt[g, 1], gap[g], right[g]
    o = np.empty(2)
    o[0], o[1] = ox, oy
    best, best_len, qb, tqb = _shortest(seg, o, pp2, gap2, right2, tol)
    pos_p = np.empty(ng)
    for g in range(ng):
        pos_p[g] = 2 * gap[g] + 1 if right[g] else 2 * gap[g] + 2
    for r in range(n_near):
        g, h = near_of[r], ng + r
        if not np.isfinite(best_len[h]):
            continue
        nearer = (np.hypot(0.5 * (alt[g, 0] + qb[h, 0]) - ox, 0.5 * (alt[g, 1] + qb[h, 1]) - oy)
                  < np.hypot(0.5 * (pp[g, 0] + qb[g, 0]) - ox, 0.5 * (pp[g, 1] + qb[g, 1]) - oy))
        if best_len[h] <= best_len[g] + _ALT_SLACK and nearer:
            pp[g, 0], pp[g, 1], best[g], best_len[g] = alt[g, 0], alt[g, 1], best[h], best_len[h]
            qb[g, 0], qb[g, 1], tqb[g] = qb[h, 0], qb[h, 1], tqb[h]
            pos_p[g] = 2 * gap[g] if right[g] else 2 * gap[g] + 3
    a = np.empty((ng, 2))
    b = np.empty((ng, 2))
    code = np.empty(ng, dtype=np.int64)
    lo = np.empty(ng)
    hi = np.empty(ng)
    occl = np.empty(ng, dtype=np.int64)
    keep = np.empty(ng, dtype=np.bool_)
    for g in range(ng):
        j = gap[g]
        if not np.isfinite(best_len[g]):
            code[g] = 2
        else:
            code[g] = 0 if best_len[g] >= passage_width else 1
        pos_q = 2 * best[g] + tqb[g]
        if right[g]:
            a[g, 0], a[g, 1], b[g, 0], b[g, 1] = pp[g, 0], pp[g, 1], qb[g, 0], qb[g, 1]
        else:
            a[g, 0], a[g, 1], b[g, 0], b[g, 1] = qb[g, 0], qb[g, 1], pp[g, 0], pp[g, 1]
        lo[g], hi[g] = min(pos_p[g], pos_q), max(pos_p[g], pos_q)
        occl[g] = 0 if right[g] else 1
        if code[g] == 2 or no_ret[g]:  # the segment joining the surfaces' ends
            a[g, 0], a[g, 1] = seg[j, 1, 0], seg[j, 1, 1]
            b[g, 0], b[g, 1] = seg[j + 1, 0, 0], seg[j + 1, 0, 1]
            lo[g], hi[g] = 2 * j + 1, 2 * j + 2
        if no_ret[g]:
            occl[g] = -1
            code[g] = 0 if np.hypot(b[g, 0] - a[g, 0], b[g, 1] - a[g, 1]) >= passage_width else 1
        abx, aby = b[g, 0] - a[g, 0], b[g, 1] - a[g, 1]
        qx, qy, _ = closest_point(0.0, 0.0, a[g, 0], a[g, 1], abx, aby)
        keep[g] = not (code[g] == 0 and np.hypot(qx - 0.0, qy - 0.0) < rear_closure)
    # the outermost of nested covers (order: lexsort((-hi, lo)), stable)
    kept = np.flatnonzero(keep)
    n_keep = len(kept)
    neg_hi = np.empty(n_keep)
    for i in range(n_keep):
        neg_hi[i] = -hi[kept[i]]
    o1 = np.argsort(neg_hi, kind="mergesort")
    lo1 = np.empty(n_keep)
    for i in range(n_keep):
        lo1[i] = lo[kept[o1[i]]]
    o2 = np.argsort(lo1, kind="mergesort")
    sel = np.empty(n_keep, dtype=np.int64)
    n_sel = 0
    last_hi = -np.inf
    for i in range(n_keep):
        g = kept[o1[o2[i]]]
        if lo[g] >= last_hi - 1e-9:
            sel[n_sel] = g
            n_sel += 1
            last_hi = hi[g]
    sel = sel[:n_sel]
    return a[sel], b[sel], code[sel], lo[sel], hi[sel], occl[sel], ng - n_keep
