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

import dataclasses
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


def find_covers(surf: Surfaces, p: MapperParams) -> Covers:
    """Covers of every gap of one view; see the module docstring."""
    seg = surf.segments
    m = len(seg)
    empty = np.zeros((0, 2))
    if m < 2:
        z = np.zeros(0)
        return Covers(empty, empty, np.zeros(0, dtype=object), z, z, np.zeros(0, dtype=int))
    o = np.asarray(surf.points.origin)
    gap = np.flatnonzero(surf.cluster[:-1] != surf.cluster[1:])  # gap g lies between gap[g] and +1
    no_ret = surf.points.gap_no_return[surf.pidx[gap + 1, 0]]
    end_j = seg[gap, 1]
    start_n = seg[gap + 1, 0]
    right = np.hypot(*(end_j - o).T) <= np.hypot(*(start_n - o).T)  # P = end of j, opening CCW
    pp = np.where(right[:, None], end_j, start_n)

    # In a thick wall the occluding end is the far edge of a jamb's side: the same gap covered from
    # the side's other end (the jamb's edge facing the robot) is as short, and it is the doorway
    # the robot meets first. Take it when no more than ``_ALT_SLACK`` longer and nearer the laser.
    # Each gap's search is independent of the others': both ends' are one call.
    alt = np.where(right[:, None], seg[gap, 0], seg[gap + 1, 1])
    near = np.flatnonzero(np.hypot(*(alt - pp).T) <= _JAMB_MAX)
    g = len(gap)
    found = _shortest(
        seg, o, np.concatenate([pp, alt[near]]), np.concatenate([gap, gap[near]]),
        np.concatenate([right, right[near]]), p.visibility_tolerance,
    )
    best, best_len, qb, tqb = (f[:g] for f in found)
    pos_p = np.where(right, 2 * gap + 1, 2 * gap + 2).astype(float)
    has = np.isfinite(best_len[near])
    jamb = near[has]
    if len(jamb):
        a_best, a_len, a_qb, a_tqb = (f[g:][has] for f in found)
        nearer = np.hypot(*(0.5 * (alt[jamb] + a_qb) - o).T) < np.hypot(*(0.5 * (pp[jamb] + qb[jamb]) - o).T)
        use = np.isfinite(a_len) & (a_len <= best_len[jamb] + _ALT_SLACK) & nearer
        j = jamb[use]
        pp[j], best[j], best_len[j] = alt[j], a_best[use], a_len[use]
        qb[j], tqb[j] = a_qb[use], a_tqb[use]
        pos_p[j] = np.where(right[j], 2 * gap[j], 2 * gap[j] + 3)
    label = np.where(best_len >= p.passage_width, EXIT, CLOSED).astype(object)
    label[~np.isfinite(best_len)] = OPEN
    pos_q = 2 * best + tqb
    a = np.where(right[:, None], pp, qb)
    b = np.where(right[:, None], qb, pp)
    lo, hi = np.minimum(pos_p, pos_q), np.maximum(pos_p, pos_q)
    occl = np.where(right, 0, 1)
    # an open gap, or a no-return gap: the segment joining the surfaces' ends
    join = (label == OPEN) | no_ret
    a[join], b[join] = end_j[join], start_n[join]
    lo[join], hi[join] = 2 * gap[join] + 1, 2 * gap[join] + 2
    occl[no_ret] = -1
    wide = np.hypot(*(b - a).T) >= p.passage_width
    label[no_ret] = np.where(wide[no_ret], EXIT, CLOSED)
    # The robot standing in a doorway: the exit across it runs through its own footprint (within
    # rear_closure of the robot centre). That is the way in or on, not a boundary of what it sees;
    # truncated there, the view would be a sliver behind the robot, the next scan would cross its
    # front and make another ASR, and so on until the robot cleared the doorway.
    at_robot = segment_distance(np.zeros(len(a)), np.zeros(len(a)), np.stack([a, b], axis=1))
    keep = ~((label == EXIT) & (at_robot < p.rear_closure))
    c = _select(Covers(a[keep], b[keep], label[keep], lo[keep], hi[keep], occl[keep]))
    return c if keep.all() else dataclasses.replace(c, through_robot=int(np.count_nonzero(~keep)))


def _select(c: Covers) -> Covers:
    """Keep the outermost of nested covers; identical or crossing later ones are dropped."""
    if len(c) == 0:
        return c
    order = np.lexsort((-c.hi, c.lo))
    keep = []
    last_hi = -np.inf
    for i in order.tolist():  # one step per gap, not per beam
        if c.lo[i] >= last_hi - 1e-9:
            keep.append(i)
            last_hi = c.hi[i]
    k = np.asarray(keep, dtype=int)
    return Covers(c.a[k], c.b[k], c.label[k], c.lo[k], c.hi[k], c.occluding[k])
