"""Growing one ASR while the robot is inside it (method.md §3), ASR frame, metres.

Each viewpoint's truncated view polygon (:mod:`mapper.view`), placed by the robot's localised pose
in the ASR frame, is unioned into the ASR polygon, together with the robot's path between the
viewpoints buffered by ``rear_closure`` (the robot's own swept footprint, which is free space: it
keeps the ASR connected and containing every viewpoint even when a view is small).

**Choice (better than recomputing from all viewpoints each scan):** method.md recomputes the ASR
from the whole occlusion map every scan. A view polygon is observed free space truncated at that
view's exits, so the union of all views equals that recomputation whenever the views agree, and it
can be kept *incrementally*: one polygon union per viewpoint, independent of how many viewpoints
came before. An exit of an earlier view that a later view sees past (covered by surfaces behind
it) ends up inside the union and disappears from the boundary; ``unknown`` edges shrink the same
way. The union is made valid (the largest part, holes dropped: an ASR boundary is one ring) and
simplified to ``simplify_tolerance``.

Labels of the final boundary are found geometrically, which survives union and simplification: an
edge lying along (within ``label_tolerance``, parallel to within 20°) a stored exit segment is
``exit``; along a stored surface segment (visible surfaces and closed gaps of every view) is
``surface``; else ``unknown``. Exit endpoints are first inserted into the boundary as vertices, so
an exit in a straight wall keeps its own edge after simplification. Stored segments that end up
inside the polygon can never be on the boundary again (the union only grows) and are dropped, so
the label store stays proportional to the boundary.

The ASR's exits are the runs of ``exit`` edges at least ``passage_width`` wide (narrower remnants,
partly covered by other views, are relabelled ``unknown``). Ids ``"<asr>/<n>"`` are kept from one
update to the next for the exit whose midpoint is nearest (within half its width, at least 0.5 m).
The centre is the centroid, or ``point_on_surface`` when the centroid falls outside (``centre_rule``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import shapely

from mapper.cycles import PARALLEL, centre_of
from mapper.exits import closest_point
from mapper.jit import kernel
from mapper.params import MapperParams
from mapper.se2 import Pose, transform_points
from mapper.types import ASR, Exit
from mapper.view import View, valid_polygon

_SAMPLES = np.linspace(0.1, 0.9, 5)  # fractions along an exit tested for being covered by surfaces


@kernel
def _pairs_sorted(
    p: np.ndarray, seg: np.ndarray, tol: float, u: np.ndarray, cos_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (point, segment) pairs closer than ``tol`` (m): point and segment indices and distances
    (in no particular order). With ``cos_min`` > -1, only the pairs whose point direction ``u``
    (P, 2, unit vectors) is parallel to the segment's to within that cosine (:data:`PARALLEL`:
    20°); else ``u`` is not read.

    Candidates are the points inside each segment's bounding box grown by ``tol``: the points sorted
    by x (stably), each box's x-range is two binary searches, and only the pairs in those ranges are
    tested on y and then by exact distance (:func:`_pairs_in_boxes`). The cost follows the
    candidates, not the product of the sizes of an ASR's boundary and label store. Compiled,
    callable from other kernels."""
    order = np.argsort(p[:, 0], kind="mergesort")
    pu = u[order] if cos_min > -1.0 else u
    return _pairs_in_boxes(p[order], order, seg, tol, pu, cos_min)


@kernel
def _pairs_in_boxes(
    ps: np.ndarray, order: np.ndarray, seg: np.ndarray, tol: float, pu: np.ndarray, cos_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_pairs_sorted` over the points ``ps`` sorted by x (``order``: their indices before
    sorting; ``pu``: their directions, when ``cos_min`` > -1), segment by segment. Compiled
    (:mod:`mapper.jit`)."""
    xs = ps[:, 0]
    cap = 64
    pi = np.empty(cap, dtype=np.int64)
    si = np.empty(cap, dtype=np.int64)
    dd = np.empty(cap)
    n = 0
    for k in range(seg.shape[0]):
        ax, ay = seg[k, 0, 0], seg[k, 0, 1]
        bx, by = seg[k, 1, 0], seg[k, 1, 1]
        lo_y, hi_y = min(ay, by) - tol, max(ay, by) + tol
        i0 = np.searchsorted(xs, min(ax, bx) - tol, side="left")
        i1 = np.searchsorted(xs, max(ax, bx) + tol, side="right")
        abx, aby = bx - ax, by - ay
        norm = max(math.hypot(abx, aby), 1e-12)
        sx, sy = abx / norm, aby / norm
        for i in range(i0, i1):
            px, py = ps[i, 0], ps[i, 1]
            if py < lo_y or py > hi_y:
                continue
            qx, qy, _ = closest_point(px, py, ax, ay, abx, aby)
            d = math.hypot(qx - px, qy - py)
            if d < tol and (cos_min <= -1.0 or abs(pu[i, 0] * sx + pu[i, 1] * sy) > cos_min):
                if n == cap:
                    cap *= 2
                    pi, si, dd = _grown(pi, cap), _grown(si, cap), _grown(dd, cap)
                pi[n], si[n], dd[n] = order[i], k, d
                n += 1
    return pi[:n], si[:n], dd[:n]


@kernel
def _grown(a: np.ndarray, size: int) -> np.ndarray:
    out = np.empty(size, dtype=a.dtype)
    out[: len(a)] = a
    return out


def _lying_along(seg: np.ndarray, others: np.ndarray, tol: float) -> np.ndarray:
    """(N,) True where a segment (N, 2, 2) lies along one of ``others`` (M, 2, 2): its midpoint
    within ``tol`` (m) of one, and parallel to it."""
    out = np.zeros(len(seg), dtype=bool)
    if len(seg) == 0 or len(others) == 0:
        return out
    seg = _as_segments(seg)
    mid = 0.5 * (seg[:, 0] + seg[:, 1])
    out[_pairs_sorted(mid, _as_segments(others), tol, _unit_directions(seg), PARALLEL)[0]] = True
    return out


def _covered(seg: np.ndarray, surfaces: np.ndarray, tol: float) -> np.ndarray:
    """(N,) True where a segment (N, 2, 2) is covered by ``surfaces`` (M, 2, 2): three of five points
    along it (``_SAMPLES``) lie along one of them (within ``tol``, m, and parallel)."""
    if len(seg) == 0 or len(surfaces) == 0:
        return np.zeros(len(seg), dtype=bool)
    return _covered_by(_as_segments(seg), _as_segments(surfaces), tol)


def _as_segments(seg: np.ndarray) -> np.ndarray:
    """Segments as the kernels take them: C-contiguous float64 (one compiled version each)."""
    return np.ascontiguousarray(seg, dtype=float)


@kernel
def _unit_directions(seg: np.ndarray) -> np.ndarray:
    """(N, 2) the unit direction of each segment (N, 2, 2) from its first end to its second (a
    zero-length one: divided by 1e-12 instead of 0), as ``ab / np.maximum(np.hypot(*ab.T), 1e-12)``."""
    u = np.empty((seg.shape[0], 2))
    for i in range(seg.shape[0]):
        abx, aby = seg[i, 1, 0] - seg[i, 0, 0], seg[i, 1, 1] - seg[i, 0, 1]
        norm = max(np.hypot(abx, aby), 1e-12)
        u[i, 0], u[i, 1] = abx / norm, aby / norm
    return u


@kernel
def _covered_by(seg: np.ndarray, surfaces: np.ndarray, tol: float) -> np.ndarray:
    """:func:`_covered` in one compiled call: the points ``a + f ab`` (f in ``_SAMPLES``) of each
    segment, in that order, with the segment's direction, searched by :func:`_pairs_sorted`."""
    n, k = seg.shape[0], _SAMPLES.shape[0]
    u = _unit_directions(seg)
    pts, dirs = np.empty((n * k, 2)), np.empty((n * k, 2))
    for i in range(n):
        abx, aby = seg[i, 1, 0] - seg[i, 0, 0], seg[i, 1, 1] - seg[i, 0, 1]
        for j in range(k):
            pts[i * k + j, 0] = seg[i, 0, 0] + _SAMPLES[j] * abx
            pts[i * k + j, 1] = seg[i, 0, 1] + _SAMPLES[j] * aby
            dirs[i * k + j, 0], dirs[i * k + j, 1] = u[i, 0], u[i, 1]
    hit = np.zeros(n * k, dtype=np.bool_)
    hit[_pairs_sorted(pts, surfaces, tol, dirs, PARALLEL)[0]] = True
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        out[i] = np.count_nonzero(hit[i * k : (i + 1) * k]) >= 3
    return out


def _add_new(stores: list[np.ndarray], segs: list[np.ndarray], tol: float) -> list[np.ndarray]:
    """Each store plus those of its new segments it does not already cover (all (N, 2, 2), m).

    A wall seen from every viewpoint would otherwise be stored once per view: a new segment is
    kept unless its two ends and its midpoint all lie along stored ones of its own store (within
    ``tol``, parallel; :func:`_along_store`)."""
    out = []
    for store, seg in zip(stores, segs, strict=True):
        if len(store) and len(seg):
            seg = seg[~_along_store(_as_segments(seg), _as_segments(store), tol)]
        out.append(np.concatenate([store, seg]) if len(seg) else store)
    return out


@kernel
def _along_store(seg: np.ndarray, store: np.ndarray, tol: float) -> np.ndarray:
    """(N,) True where a segment's (N, 2, 2) first end, midpoint and second end all lie along
    segments of ``store`` (M, 2, 2) (within ``tol``, m, and parallel), in one compiled call."""
    n = seg.shape[0]
    u = _unit_directions(seg)
    pts, dirs = np.empty((3 * n, 2)), np.empty((3 * n, 2))
    for i in range(n):
        for c in range(2):
            pts[i, c] = seg[i, 0, c]
            pts[n + i, c] = 0.5 * (seg[i, 0, c] + seg[i, 1, c])
            pts[2 * n + i, c] = seg[i, 1, c]
            dirs[i, c] = dirs[n + i, c] = dirs[2 * n + i, c] = u[i, c]
    hit = np.zeros(3 * n, dtype=np.bool_)
    hit[_pairs_sorted(pts, store, tol, dirs, PARALLEL)[0]] = True
    return hit[:n] & hit[n : 2 * n] & hit[2 * n :]


@kernel
def _with_ends(v: np.ndarray, x: np.ndarray, tol: float, gap: float) -> np.ndarray:
    """The ring ``v`` (V, 2, not closed; edge i from v[i] to v[i + 1]) with the points ``x`` (P, 2)
    inserted as vertices where they lie on it: each point's nearest edge closer than ``tol`` (the
    first of equals), the point's foot on it (its fraction t along it), when that foot lies more than
    ``gap`` from both of the edge's ends; in ring order (by edge, then t), one vertex for feet
    within ``gap`` of the one before. ``v`` itself when none is (m, one frame). Compiled."""
    nv, m = v.shape[0], x.shape[0]
    edges = np.empty((nv, 2, 2))
    for i in range(nv):
        j = i + 1 if i + 1 < nv else 0
        edges[i, 0, 0], edges[i, 0, 1], edges[i, 1, 0], edges[i, 1, 1] = v[i, 0], v[i, 1], v[j, 0], v[j, 1]
    pi, si, d = _pairs_sorted(x, edges, tol, np.zeros((0, 2)), -1.0)
    e, dist = np.zeros(m, dtype=np.int64), np.full(m, np.inf)
    for k in range(len(pi)):  # each point's nearest edge, the first of equals
        i = pi[k]
        if d[k] < dist[i] or (d[k] == dist[i] and si[k] < e[i]):
            e[i], dist[i] = si[k], d[k]
    sel_e, sel_t = np.empty(m, dtype=np.int64), np.empty(m)
    n = 0
    for i in range(m):
        ax, ay = edges[e[i], 0, 0], edges[e[i], 0, 1]
        abx, aby = edges[e[i], 1, 0] - ax, edges[e[i], 1, 1] - ay
        length = np.hypot(abx, aby)
        t = min(max(((x[i, 0] - ax) * abx + (x[i, 1] - ay) * aby) / max(length * length, 1e-18), 0.0), 1.0)
        along = t * length  # distance from the edge's start (m)
        if dist[i] < tol and along > gap and length - along > gap:
            # insertion sort by (edge, t), stable: ring order, equal keys in the points' order
            at = n
            while at > 0 and (sel_e[at - 1] > e[i] or (sel_e[at - 1] == e[i] and sel_t[at - 1] > t)):
                sel_e[at], sel_t[at] = sel_e[at - 1], sel_t[at - 1]
                at -= 1
            sel_e[at], sel_t[at] = e[i], t
            n += 1
    if n == 0:
        return v
    new = np.empty((n, 2))
    for k in range(n):
        a, b = edges[sel_e[k], 0], edges[sel_e[k], 1]
        new[k, 0], new[k, 1] = a[0] + sel_t[k] * (b[0] - a[0]), a[1] + sel_t[k] * (b[1] - a[1])
    keep = np.ones(n, dtype=np.bool_)  # one vertex for coinciding insertions (abutting exits' ends)
    for k in range(1, n):
        keep[k] = np.hypot(new[k, 0] - new[k - 1, 0], new[k, 1] - new[k - 1, 1]) > gap
    out = np.empty((nv + np.count_nonzero(keep), 2))
    o, k = 0, 0
    for j in range(nv + 1):  # the kept points of edge j - 1 go before v[j]
        while k < n and sel_e[k] + 1 == j:
            if keep[k]:
                out[o, 0], out[o, 1] = new[k, 0], new[k, 1]
                o += 1
            k += 1
        if j < nv:
            out[o, 0], out[o, 1] = v[j, 0], v[j, 1]
            o += 1
    return out


_UNKNOWN, _SURFACE, _EXIT = 0, 1, 2  # edge label codes of the kernels
_LABELS = np.array(["unknown", "surface", "exit"], dtype=object)  # code -> label


@kernel
def _edge_labels(v: np.ndarray, store: np.ndarray, ne: int, tol: float) -> np.ndarray:
    """(V,) the label code of each edge of the ring ``v`` (V, 2; edge i from v[i] to v[i + 1]):
    ``_EXIT`` where it lies along (its midpoint within ``tol``, m, and parallel) one of the first
    ``ne`` segments of ``store`` (the exit segments), else ``_SURFACE`` where along one of the
    others (surfaces), else ``_UNKNOWN``. Compiled (:mod:`mapper.jit`)."""
    nv = v.shape[0]
    mid, u = np.empty((nv, 2)), np.empty((nv, 2))
    for i in range(nv):
        j = i + 1 if i + 1 < nv else 0
        dx, dy = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1]
        mid[i, 0], mid[i, 1] = 0.5 * (v[i, 0] + v[j, 0]), 0.5 * (v[i, 1] + v[j, 1])
        norm = max(np.hypot(dx, dy), 1e-12)
        u[i, 0], u[i, 1] = dx / norm, dy / norm
    codes = np.full(nv, _UNKNOWN, dtype=np.int64)
    if store.shape[0] == 0:
        return codes
    ei, si, _ = _pairs_sorted(mid, store, tol, u, PARALLEL)
    for k in range(len(ei)):  # an edge along both is an exit
        codes[ei[k]] = max(codes[ei[k]], _EXIT if si[k] < ne else _SURFACE)
    return codes


@kernel
def _runs(v: np.ndarray, codes: np.ndarray, code: int, narrow: int, width: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """The maximal runs of edges labelled ``code`` round the ring ``v`` (V, 2) at least ``width``
    (m) from end to end: the indices into ``v`` of each run's first and last vertex, in ring order
    from the first edge not in a run. The edges of narrower runs are relabelled ``narrow`` in
    ``codes``. None when every edge or none is ``code`` (empty arrays). Compiled (:mod:`mapper.jit`)."""
    n = codes.shape[0]
    shift = -1
    for j in range(n):
        if codes[j] != code:
            shift = j
            break
    ia, ib = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    if shift < 0:
        return ia[:0], ib[:0]
    k, start = 0, -1
    for j in range(n + 1):  # start at shift, so that no run wraps round it
        cur = j < n and codes[(j + shift) % n] == code
        if cur and start < 0:
            start = j
        elif not cur and start >= 0:
            a, b = (start + shift) % n, (j + shift) % n
            if np.hypot(v[b, 0] - v[a, 0], v[b, 1] - v[a, 1]) >= width:
                ia[k], ib[k] = a, b
                k += 1
            else:
                for r in range(start, j):
                    codes[(r + shift) % n] = narrow
            start = -1
    return ia[:k], ib[:k]


@kernel
def _nearest_old(ab: np.ndarray, old: np.ndarray) -> np.ndarray:
    """For each new exit (segments ``ab`` (R, 2, 2), in order) the old exit (midpoints ``old``
    (O, 2)) whose midpoint is nearest its own, within half its width and at least 0.5 m, not yet
    taken by an earlier one (the first of equals); -1 where none is (m, one frame). Compiled."""
    taken = np.zeros(old.shape[0], dtype=np.bool_)
    out = np.full(ab.shape[0], -1, dtype=np.int64)
    for r in range(ab.shape[0]):
        mx, my = 0.5 * (ab[r, 0, 0] + ab[r, 1, 0]), 0.5 * (ab[r, 0, 1] + ab[r, 1, 1])
        best_d = max(0.5, 0.5 * np.hypot(ab[r, 1, 0] - ab[r, 0, 0], ab[r, 1, 1] - ab[r, 0, 1]))
        for i in range(old.shape[0]):
            d = np.hypot(old[i, 0] - mx, old[i, 1] - my)
            if not taken[i] and d < best_d:
                out[r], best_d = i, d
        if out[r] >= 0:
            taken[out[r]] = True
    return out


def _transform_segments(pose: Pose, seg: np.ndarray) -> np.ndarray:
    return transform_points(pose, seg.reshape(-1, 2)).reshape(-1, 2, 2)


class AsrBuilder:
    """The growing polygon, labels and exits of one ASR; ``asr`` is the record it keeps current."""

    def __init__(self, asr_id: int, created: float, origin: Pose, params: MapperParams):
        self.p = params
        self.asr = ASR(asr_id, created, origin, np.zeros((0, 2)), [], (0.0, 0.0))
        self.polygon = shapely.Polygon()
        self.surfaces = np.zeros((0, 2, 2))
        self.exit_segments = np.zeros((0, 2, 2))
        self.viewpoints: list[Pose] = []
        self._last_viewpoint: Pose | None = None
        self._gate_cache: tuple | None = None
        self._pruned_size = 16
        self._recorded = 0  # viewpoints appended by _record (see add_view)
        self._next_exit = 0
        self.stale = False  # the polygon grew but the record was not relabelled yet
        self._unstored: tuple[np.ndarray, np.ndarray] | None = None  # a view's segments, not yet stored
        # Ids of the exits the robot was seen to cross (its path from one pose to the next cut the
        # chord): never explained away as walls. Not an entrance, which is the nearest exit to
        # where the robot came in, and can be a wall seen too sparsely beside the doorway. Not in
        # the map document: a map continued from one protects the exits crossed since.
        self.crossed: set[str] = set()

    def add_view(self, view: View, pose: Pose, relabel: bool = True) -> bool:
        """Union the view seen from ``pose`` (ASR frame) into the ASR; True when the ASR changed.

        With ``relabel`` False only the polygon is updated now; the label store (the view's surface
        and exit segments) and the record's boundary, labels, exits and centre when
        :meth:`ensure_labels` is called (``stale`` until then); every method that needs them calls
        it first."""
        self.ensure_labels()
        p = self.p
        robot = shapely.Point(pose[:2])
        if len(self.viewpoints) > self._recorded:
            # a pose appended from outside (the older way to say "the robot did not walk here from
            # the last viewpoint"): honour it as restart_path(), keep only viewpoints this ASR holds
            del self.viewpoints[self._recorded :]
            self.restart_path()
        vpoly = shapely.transform(view.polygon, lambda c: transform_points(pose, c))
        pieces = [vpoly]
        if self._last_viewpoint is not None:
            path = shapely.LineString([self._last_viewpoint[:2], pose[:2]])
            pieces.append(path.buffer(p.rear_closure, quad_segs=2))
        self._last_viewpoint = pose
        self.asr.scans += 1
        world_surfaces = _transform_segments(pose, view.surfaces)
        gates = self._gates(world_surfaces)
        new = shapely.union_all(pieces) if len(pieces) > 1 else pieces[0]
        if gates is not None:
            near = gates[shapely.intersects(gates, new)]  # most gates are far from this view
            if len(near):
                new = shapely.difference(new, near[0] if len(near) == 1 else shapely.union_all(near))
        grown = shapely.union(self.polygon, new)
        if grown.is_empty:  # nothing seen yet (every beam no return, or the laser covered)
            return False
        if self.polygon.area > 0 and grown.area - self.polygon.area < p.min_area_gain:
            self._record(pose, robot)
            return False
        self.polygon = self._single_ring(grown, robot)
        # the label store takes the view's segments when next relabelled (nothing reads it before)
        self._unstored = (world_surfaces, _transform_segments(pose, view.exits))
        self._record(pose, robot)
        if relabel:
            self._relabel()
        else:
            self.stale = True
        return True

    def ensure_labels(self) -> None:
        """Bring the record's boundary, labels, exits and centre up to date with the polygon."""
        if self.stale:
            self.stale = False
            self._relabel()

    def clip_growth(self, before: shapely.Polygon, area: shapely.Geometry, robot: tuple[float, float]
                    ) -> bool:
        """Keep the ASR's growth since ``before`` (its polygon then) within ``area`` (ASR frame): what
        it held before stays, so a clip through its middle cannot keep just the part round the frame's
        origin. The labels follow when next needed (``stale``). True when anything was cut."""
        if self.polygon.difference(area).area < self.p.min_area_gain:
            return False
        grown = shapely.intersection(self.polygon, area)
        kept = grown if before.is_empty else shapely.union(before, grown)
        self.polygon = self._single_ring(kept, shapely.Point(robot))
        if self.polygon.area < before.area - self.p.min_area_gain:
            # The union came apart where ``before``'s two parts meet at a point (a neck narrower than
            # 1 µm), and the part round the origin alone would lose what the ASR held (lab seed 4:
            # 27.9 -> 7.6 m², leaving its cycle's match's centre 3 m outside it): keep ``before``.
            self.polygon = before
        if self.viewpoints:  # a viewpoint in the part cut off is no longer one of this ASR's
            xy = np.array([v[:2] for v in self.viewpoints])
            inside = shapely.covers(self.polygon, shapely.points(xy))
            self.viewpoints = [v for v, k in zip(self.viewpoints, inside, strict=True) if k]
            self._recorded = len(self.viewpoints)
        self.stale = True
        return True

    def restart_path(self) -> None:
        """The robot did not walk here from the last viewpoint (it re-entered this ASR): the next
        view is not joined to the previous one by the swept corridor."""
        self._last_viewpoint = None

    def _record(self, pose: Pose, robot: shapely.Point) -> None:
        """Keep ``pose`` as a viewpoint of this ASR if the ASR holds it (and there is room)."""
        if len(self.viewpoints) < self.p.max_viewpoints and self.polygon.covers(robot):
            self.viewpoints.append(pose)
        self._recorded = len(self.viewpoints)

    def open_exit(self, at: tuple[float, float], accept: Callable[[Exit], bool] | None = None) -> Exit | None:
        """Open an exit where the robot left through a non-exit edge (ASR frame, m).

        The robot may leave through an ``unknown`` edge (unexplored periphery) or where the views
        never showed a gap: that place is an exit, ``passage_width`` wide along the boundary,
        centred on the point ``at`` nearest to where the robot left. With ``accept``, the exit is
        kept only if ``accept(exit)``; else the ASR is left as it was and None returned.
        """
        self.ensure_labels()
        if accept is not None:
            saved = (self.exit_segments, list(self.asr.exits), self.asr.boundary, list(self.asr.edges),
                     self._next_exit)
            e = self.open_exit(at)
            if accept(e):
                return e
            self.exit_segments, self.asr.exits, self.asr.boundary, self.asr.edges, self._next_exit = saved
            return None
        ring = self.polygon.exterior
        d = ring.project(shapely.Point(at))
        h = 0.5 * self.p.passage_width
        for _ in range(8):  # widen along a bent boundary until the chord is a passage wide
            a = ring.interpolate((d - h) % ring.length)
            b = ring.interpolate((d + h) % ring.length)
            if a.distance(b) >= self.p.passage_width or 2 * h >= ring.length / 2:
                break
            h *= 1.25
        if not ring.is_ccw:
            a, b = b, a
        seg = np.array([[[a.x, a.y], [b.x, b.y]]])
        self.exit_segments = np.concatenate([self.exit_segments, seg])
        self._relabel()
        mid = 0.5 * (seg[0, 0] + seg[0, 1])
        near = min(self.asr.exits, key=lambda e: np.hypot(*(np.asarray(e.midpoint) - mid)), default=None)
        if near is None or np.hypot(*(np.asarray(near.midpoint) - mid)) > self.p.passage_width:
            # the boundary bends too much there for an exit edge: record the chord itself, at least
            # a passage wide (the robot did pass there)
            c = seg[0, 1] - seg[0, 0]
            half = 0.5 * max(float(np.hypot(*c)), self.p.passage_width)
            c = c / max(float(np.hypot(*c)), 1e-12)
            ea, eb = mid - half * c, mid + half * c
            near = Exit(
                f"{self.asr.id}/{self._next_exit}", (float(ea[0]), float(ea[1])), (float(eb[0]), float(eb[1]))
            )
            self._next_exit += 1
            self.asr.exits.append(near)
        return near

    def _gates(self, seen: np.ndarray) -> np.ndarray | None:
        """What lies beyond the ASR's exits (an array of polygons, ASR frame): later views must not
        grow into it.

        Without this the views taken near a doorway, which see through it, would swallow the next
        room and the robot would never leave the ASR. Each exit's gate is a trapezoid from the exit
        outward, widening at 45°, ``gate_depth`` deep (where it overlaps the ASR, the union with the
        ASR restores the ASR). An exit that the new view sees covered by surfaces (``seen``, ASR
        frame: three of five points along it lie along a surface) was explained away: it gets no
        gate, and its stored exit segments are dropped so the boundary there can become surface.
        The gates change only when the exits do, so they are cached between views.
        """
        p = self.p
        exits = self.asr.exits
        if not exits:
            return None
        a = np.array([e.a for e in exits])
        b = np.array([e.b for e in exits])
        ab = b - a
        s = ab / np.maximum(np.hypot(ab[:, 0], ab[:, 1]), 1e-12)[:, None]
        # an exit the robot was seen to cross is not a wall, however a view sees it (see _relabel)
        explained = _covered(np.stack([a, b], axis=1), seen, p.label_tolerance)
        explained &= np.array([e.id not in self.crossed for e in exits])
        if explained.any() and len(self.exit_segments):
            gone = np.stack([a[explained], b[explained]], axis=1)
            es = self.exit_segments
            self.exit_segments = es[~_lying_along(es, gone, p.label_tolerance)]
        keep = ~explained
        key = (a[keep].tobytes(), b[keep].tobytes())
        if self._gate_cache is not None and self._gate_cache[0] == key:
            return self._gate_cache[1]
        n = np.stack([s[keep, 1], -s[keep, 0]], axis=1)  # right of a->b: outside (CCW boundary)
        d = p.gate_depth
        ak, bk, sk = a[keep], b[keep], s[keep]
        quads = np.stack([ak, bk, bk + d * (n + sk), ak + d * (n - sk)], axis=1)
        gates = shapely.polygons(quads) if len(quads) else None
        self._gate_cache = (key, gates)
        return gates

    def _passed(self, seg: np.ndarray) -> np.ndarray:
        """(N,) True where a stored exit segment (N, 2, 2; ASR frame) lies along an exit the robot
        was seen to cross (:attr:`crossed`)."""
        passed = np.array([(e.a, e.b) for e in self.asr.exits if e.id in self.crossed], dtype=float)
        return _lying_along(seg, passed.reshape(-1, 2, 2), self.p.label_tolerance)

    def _single_ring(self, g: shapely.Geometry, robot: shapely.Point) -> shapely.Polygon:
        """Valid, one ring, simplified, no holes: the part holding the ASR's origin (the first
        viewpoint, so earlier viewpoints are never cut off), or the robot for the first view."""
        g = g if g.is_valid else shapely.make_valid(g)
        if isinstance(g, shapely.Polygon) and g.area > 0 and shapely.get_num_interior_rings(g) == 0:
            poly = g  # the usual case: already one ring (the same coordinates as its exterior's polygon)
        else:
            parts = [q for q in shapely.get_parts(g) if isinstance(q, shapely.Polygon) and q.area > 0]
            if not parts:
                return self.polygon
            anchor = shapely.Point(0.0, 0.0) if self.polygon.area > 0 else robot
            holding = [q for q in parts if q.covers(anchor)]
            poly = max(holding or parts, key=lambda q: q.area)
            poly = shapely.Polygon(poly.exterior)
        simple = poly.simplify(self.p.simplify_tolerance, preserve_topology=True)
        return valid_polygon(np.asarray(simple.exterior.coords)[:-1]) if not simple.is_valid else simple

    def _ring(self) -> np.ndarray:
        """Boundary vertices (V, 2), counter-clockwise, not closed, exit endpoints inserted (unless
        inserting them would make the ring invalid)."""
        ring = self.polygon.exterior
        v = shapely.get_coordinates(ring)[:-1]
        if not shapely.is_ccw(ring):
            v = v[::-1]
        if len(self.exit_segments) == 0:
            return v
        x = np.ascontiguousarray(self.exit_segments.reshape(-1, 2), dtype=float)
        out = _with_ends(np.ascontiguousarray(v), x, self.p.label_tolerance, self.p.simplify_tolerance)
        if len(out) == len(v):
            return v
        # A vertex of the ring can lie within rounding of another of its edges (a pinch the union
        # left, valid by 1e-15 m); points inserted on that edge are rounded too and can cross it.
        # Then the ring stays as it was: its exits' edges are found by their labels alone.
        return out if shapely.is_valid(shapely.Polygon(out)) else v

    def _relabel(self) -> None:
        p = self.p
        if self._unstored is not None:
            segs, self._unstored = self._unstored, None
            self.surfaces, self.exit_segments = _add_new(
                [self.surfaces, self.exit_segments], list(segs), 0.5 * p.label_tolerance
            )
            # A stored exit covered by a stored surface is a wall that some view saw too sparsely
            # to fit (far, at a grazing angle), not a way out; kept, it labels that wall an exit
            # (an edge along both is one), and the exits along both walls of a corridor joined its
            # doorways into one exit run.
            # Not one the robot was seen to cross (``crossed``): the walls either side of
            # a doorway, each seen reaching a little into it, and a stray return at a jamb cover
            # three of its five points (``lab`` seed 3: a view from 7 m dropped the south door
            # this way, and its transition with it; the next view through the door swallowed the
            # corridor, and the loop through it was never closed).
            dropped = _covered(self.exit_segments, self.surfaces, p.label_tolerance)
            if dropped.any():
                dropped &= ~self._passed(self.exit_segments)
                self.exit_segments = self.exit_segments[~dropped]
        v = np.ascontiguousarray(self._ring(), dtype=float)  # one layout: one compiled version
        # one candidate search over both stores: exit segments first, then surfaces
        store = _as_segments(np.concatenate([self.exit_segments, self.surfaces]))
        codes = _edge_labels(v, store, len(self.exit_segments), p.label_tolerance)
        exits = self._exit_runs(v, codes)
        self._prune()
        a = self.asr
        a.boundary, a.edges = v, _LABELS[codes].tolist()
        a.centre, a.centre_rule = centre_of(self.polygon)
        a.exits = self._keep_ids(exits)

    def _exit_runs(self, v: np.ndarray, codes: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Maximal runs of exit edges (``codes``, :func:`_edge_labels`) as (a, b) segments (ASR
        frame, m); too-narrow runs are relabelled unknown in ``codes`` (:func:`_runs`)."""
        ia, ib = _runs(v, codes, _EXIT, _UNKNOWN, self.p.passage_width)
        return list(zip(v[ia], v[ib], strict=True))

    def _prune(self) -> None:
        """Drop stored segments that lie inside the polygon: they can never be boundary again.

        Run when the store has doubled since the last pruning, which keeps it proportional to the
        boundary at a constant amortised cost per view."""
        size = len(self.surfaces) + len(self.exit_segments)
        if size < 2 * self._pruned_size:
            return
        tol = self.p.label_tolerance
        ring = self.polygon.exterior
        shapely.prepare(ring)
        for name in ("surfaces", "exit_segments"):
            seg = getattr(self, name)
            if len(seg) == 0:
                continue
            # a segment whose midpoint is farther from the boundary than tol + half its length lies
            # wholly farther than tol (one prepared, indexed distance test per segment, in GEOS)
            half = 0.5 * np.hypot(*(seg[:, 1] - seg[:, 0]).T)
            near = shapely.dwithin(shapely.points(0.5 * (seg[:, 0] + seg[:, 1])), ring, tol + half)
            setattr(self, name, seg[near])
        self._pruned_size = max(len(self.surfaces) + len(self.exit_segments), 16)

    def _keep_ids(self, runs: list[tuple[np.ndarray, np.ndarray]]) -> list[Exit]:
        """The exits of the exit ``runs`` (ASR frame, m): each keeps the id of the old exit whose
        midpoint is nearest its own, within half its width and at least 0.5 m (:func:`_nearest_old`),
        or gets a new id."""
        old = list(self.asr.exits)
        out = []
        if runs and old:
            ab = np.array(runs)  # (R, 2, 2)
            kept = _nearest_old(ab, np.array([e.midpoint for e in old])).tolist()
        else:
            kept = [-1] * len(runs)
        for (a, b), best in zip(runs, kept, strict=True):
            if best >= 0:
                e = old[best]
                out.append(Exit(e.id, (float(a[0]), float(a[1])), (float(b[0]), float(b[1])), e.to))
            else:
                out.append(
                    Exit(
                        f"{self.asr.id}/{self._next_exit}",
                        (float(a[0]), float(a[1])),
                        (float(b[0]), float(b[1])),
                    )
                )
                self._next_exit += 1
        return out
