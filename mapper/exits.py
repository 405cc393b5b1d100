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
All candidates of all gaps are evaluated in a few broadcast numpy operations.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mapper.lines import Surfaces, _cross
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


def segment_distance(px: np.ndarray, py: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance (m) from points (px, py) (...) to segments (..., 2, 2), all in one frame."""
    qx, qy, _ = closest_xy(px, py, seg)
    return np.hypot(qx - px, qy - py)


def _shortest(
    seg: np.ndarray, o: np.ndarray, pp: np.ndarray, gap: np.ndarray, right: np.ndarray, p: MapperParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each gap, the shortest visible segment from its occluding point ``pp`` across the gap.

    Returns the surface index it lands on, its length (inf: none visible), the point and the
    fraction along that surface.
    """
    m = len(seg)
    # the surfaces across each gap, nearest in sweep order first: a window of them, since a cover
    # lands within a few surfaces of its gap and the visibility test is quadratic in the window
    w = min(_WINDOW, m)
    off = np.arange(w)
    kw = np.where(right[:, None], gap[:, None] + 1 + off, gap[:, None] - off)  # (G, W)
    valid = (kw >= 0) & (kw < m)
    kw = np.clip(kw, 0, m - 1)
    segw = seg[kw]  # (G, W, 2, 2)
    px, py = pp[:, 0:1], pp[:, 1:2]
    qx, qy, tq = closest_xy(px, py, segw)  # closest points Q on the window's surfaces
    q = np.stack((qx, qy), axis=-1)
    length = np.hypot(qx - px, qy - py)
    length[~valid] = np.inf
    # only the few shortest candidates of each gap are checked for visibility: a longer one is
    # taken only when all of these are hidden, and then the gap is wide open anyway
    nc = min(_CANDIDATES, w)
    cand = np.argpartition(length, nc - 1, axis=1)[:, :nc]  # (G, C) window positions
    g_ = np.arange(len(gap))[:, None]
    clen, cq, ctq = length[g_, cand], q[g_, cand], tq[g_, cand]
    # The surfaces strictly between P and Q (window positions before Q's) must lie beyond the line
    # PQ as seen from the laser. The candidates are tried shortest first (equal lengths: in the
    # order above), each round only for the gaps whose shorter candidates were all hidden, so most
    # gaps take one round: the first visible one is the shortest visible. A gap with none keeps its
    # first candidate, at infinite length.
    g = len(gap)
    order = np.argsort(clen, axis=1, kind="stable")
    pick = np.zeros(g, dtype=int)
    best_len = np.full(g, np.inf)
    todo = np.arange(g)
    for r in range(nc):
        c = order[todo, r]
        lr = clen[todo, c]
        finite = np.isfinite(lr)  # past the last finite candidate every other is infinite too
        todo, c, lr = todo[finite], c[finite], lr[finite]
        if not len(todo):
            break
        cpos = cand[todo, c]
        wv = int(cpos.max())
        hidden = np.zeros(len(todo), dtype=bool)
        if wv > 0:
            ppt = pp[todo]
            d = cq[todo, c] - ppt  # (T, 2) line direction
            dn = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            sgn = np.where(_cross(d, o - ppt) >= 0, 1.0, -1.0)  # the laser's side of the line
            ends = segw[todo, :wv].reshape(len(todo), 2 * wv, 2) - ppt[:, None, :]  # (T, 2 wv, 2)
            side_e = _cross(d[:, None, :], ends) / dn[:, None]
            in_front = (side_e * sgn[:, None] > p.visibility_tolerance).reshape(len(todo), wv, 2).any(-1)
            inside = (off[None, :wv] < cpos[:, None]) & valid[todo, :wv]
            hidden = (inside & in_front).any(-1)
        seen = todo[~hidden]
        pick[seen], best_len[seen] = c[~hidden], lr[~hidden]
        todo = todo[hidden]
    g1 = np.arange(g)
    best = kw[g1, cand[g1, pick]]
    qb = cq[g1, pick]
    tqb = ctq[g1, pick]
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
        np.concatenate([right, right[near]]), p,
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
