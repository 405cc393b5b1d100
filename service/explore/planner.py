"""The planner (:class:`Planner`): what to do next in the mapper's current view, from unknown regions
to exits, backtracks, ``goto`` goals and the last rounds; see :mod:`service.explore`."""

from __future__ import annotations

import heapq
import logging
import math

import numpy as np
import shapely

from mapper.se2 import Pose, compose, inverse, transform_points, wrap
from mapper.types import ASR, Exit
from service.explore.crossing import crossing, depth_beyond, side_openings
from service.explore.links import centre_distance, exit_of, link_edges, within_hops
from service.explore.params import ExploreParams
from service.explore.regions import exit_normal, free_space, inside_point, shape_key, unknown_regions
from service.explore.view import Goal, MapView, Memory

log = logging.getLogger(__name__)


def _add_point(store: dict[int, list[tuple[float, float]]], asr: int, point) -> None:
    """Add ``point`` (m, ``asr``'s frame) to ``store``'s list for ``asr``."""
    store.setdefault(asr, []).append((float(point[0]), float(point[1])))


class Planner:
    """Chooses the next :class:`Goal` from a :class:`MapView` (method.md §8); see :mod:`service.explore`."""

    def __init__(self, params: ExploreParams | None = None, memory: Memory | None = None) -> None:
        self.p = params or ExploreParams()
        self.memory = memory or Memory()
        self._pending_key: tuple | None = None
        self._pending: list[tuple[float, float]] = []
        self._known_key: tuple | None = None
        self._known: list[tuple[int, shapely.Geometry]] = []
        self._polygons: list[tuple[int, shapely.Geometry]] = []
        self._geometry_cache: dict[tuple, tuple[np.ndarray, float]] = {}
        self._beyond_key: tuple | None = None
        self._beyond: dict[tuple, bool] = {}

    # -- bookkeeping ---------------------------------------------------------------------------
    def looked_at(self, asr: int, point: tuple[float, float]) -> None:
        """The unknown region at ``point`` (m, ``asr``'s frame) has been looked at."""
        self.memory.looked.setdefault(asr, []).append((float(point[0]), float(point[1])))

    def failed(self, asr: int, exit_id: str, midpoint: tuple[float, float] | None = None) -> None:
        """Exit ``exit_id`` of ``asr`` could not be crossed (its chord's ``midpoint``: m, ``asr``'s
        frame, so that a relabelled exit at the same place stays failed)."""
        self.memory.failed_exits.add((asr, exit_id))
        if midpoint is not None:
            _add_point(self.memory.failed_at, asr, midpoint)

    def crossed_into_known(self, asr: int, midpoint: tuple[float, float]) -> None:
        """The robot crossed the exit of ``asr`` at ``midpoint`` (its frame) into an ASR already
        known: that exit needs no visit (see ``Memory.crossed_at``)."""
        _add_point(self.memory.crossed_at, asr, midpoint)

    def _failed(self, asr: ASR, ex: Exit) -> bool:
        if (asr.id, ex.id) in self.memory.failed_exits:
            return True
        m = ex.midpoint
        mem = self.memory
        near = [*mem.failed_at.get(asr.id, ()), *mem.shut_at.get(asr.id, ()), *mem.crossed_at.get(asr.id, ())]
        return any(math.hypot(m[0] - q[0], m[1] - q[1]) < 0.5 for q in near)

    def shut_exits(self, view: MapView, points: np.ndarray) -> int:
        """Mark the unexplored exits of the current ASR that the scan ``points`` (robot frame, the
        robot at ``view.pose``) shows shut as explored; returns how many. Shut: at least
        ``shut_points`` returns lie in the strip just behind the exit on its normal, where the robot
        would drive through (``shut_depth`` deep beyond the ASR polygon, ``shut_width`` wide): a
        wall seen along its length through gaps in its fit, a table right behind a chord between
        two of its legs. Seen from afar, such an exit costs no trip."""
        asr = view.asrs.get(view.current) if view.current is not None else None
        if asr is None or len(points) < self.p.shut_points:
            return 0
        pts = transform_points(view.pose, points)  # into the ASR's frame
        n_shut = 0
        side = self._side_openings(asr, link_edges(view)) if self.memory.side_round else []
        for ex in [*asr.exits, *side]:
            if ex.to is not None or self._failed(asr, ex):
                continue
            n, depth = self._geometry(asr, ex)
            mid = np.asarray(ex.midpoint, dtype=float)
            if depth > 0.0:
                continue  # a run of exit edges that bends: its chord's normal says little
            rel = pts - mid
            along = rel @ n
            across = rel @ np.array([-n[1], n[0]])
            inside = (along > -0.05) & (along < self.p.shut_depth) & (np.abs(across) < self.p.shut_width / 2)
            if int(inside.sum()) >= self.p.shut_points:
                _add_point(self.memory.shut_at, asr.id, mid)
                log.info("exploration: exit %s of ASR %s is shut (a surface right behind it)", ex.id, asr.id)
                n_shut += 1
        return n_shut

    # -- queries -------------------------------------------------------------------------------
    def observe(self, asr: ASR, pose: Pose) -> int:
        """Mark the pending unknown regions of ``asr`` that the robot at ``pose`` (ASR frame) has in
        view and near as looked at; returns how many. Regions resolved by the view vanish from the
        ASR anyway; this retires the ones that stay unknown (occluded) without a trip to each."""
        if self.memory.visiting:
            return 0  # the visiting round goes to each region (ExploreParams.visit_round)
        n = 0
        for m in self.pending_unknown(asr):
            d = math.hypot(m[0] - pose[0], m[1] - pose[1])
            bearing = wrap(math.atan2(m[1] - pose[1], m[0] - pose[0]) - pose[2])
            if d < self.p.look_distance and abs(bearing) < self.p.view_half_angle:
                self.looked_at(asr.id, m)
                _add_point(self.memory.far, asr.id, m)
                n += 1
        return n

    def start_visiting(self) -> bool:
        """Begin the round that visits the unknown regions looked at from afar
        (``ExploreParams.visit_round``): they are pending again, and from now on only a visit
        retires a region. False when there is none or the round has been held already. It counts as
        a retry round (``Memory.retries``), so ``retry_budget`` bounds it."""
        mem = self.memory
        if not self.p.visit_round or mem.visiting or not any(mem.far.values()):
            return False
        mem.visiting = True
        mem.retries += 1
        for asr_id, points in mem.far.items():
            far = set(points)
            mem.looked[asr_id] = [q for q in mem.looked.get(asr_id, []) if q not in far]
        log.info("exploration: visiting %d unknown regions looked at only from afar",
                 sum(len(v) for v in mem.far.values()))
        return True

    def start_side_round(self, view: MapView) -> bool:
        """Begin the last round (``ExploreParams.side_openings``): from now on the side openings of
        linked exits (:func:`side_openings`) are exits to explore, and the exits that failed are
        tried again. False when the round has been held already or no ASR has an unexplored side
        opening. It counts as a retry round (``Memory.retries``), so ``retry_budget`` bounds it."""
        mem = self.memory
        if not self.p.side_openings or mem.side_round:
            return False
        mem.side_round = True  # held once; and _side_openings gives them only from now on
        edges = link_edges(view)
        n = sum(len([e for e in self._side_openings(a, edges) if not self.explored(view, a, e, edges)])
                for a in view.asrs.values())
        if not n:
            return False
        mem.retries += 1
        self._forget_failures()
        log.info("exploration: going through %d side openings of linked exits", n)
        return True

    def _forget_failures(self) -> None:
        """Forget the exits that failed, so that a new round tries them again."""
        self.memory.failed_exits.clear()
        self.memory.failed_at.clear()

    def retire_known_unknown(self, view: MapView, asr: ASR) -> int:
        """Mark the pending unknown regions of ``asr`` whose space is already inside other ASRs as
        looked at; returns how many. The disc of ``known_radius`` round a region's midpoint, less
        ``asr`` itself, must be at least ``known_cover`` inside the other ASRs' polygons (global
        frame): an ASR made on a return to mapped space (a gap between tables crossed, a revisit
        not recognised) need not look round again at what the map already holds."""
        pending = self.pending_unknown(asr)
        if not pending or self.p.known_cover > 1.0 or len(asr.boundary) < 3:
            return 0
        polygons = self._known_polygons(view)
        own = next((g for i, g in polygons if i == asr.id), None)
        n = 0
        for m in pending:
            q = transform_points(asr.origin, np.array([m]))[0]
            disc = shapely.Point(q).buffer(self.p.known_radius)
            if own is not None:
                disc = disc.difference(own)
            if disc.area <= 1e-6:
                continue
            if self._covered_by_others(view, asr.id, disc):
                self.looked_at(asr.id, m)
                n += 1
        return n

    def pending_unknown(self, asr: ASR) -> list[tuple[float, float]]:
        """Midpoints (ASR frame) of the unknown runs of ``asr`` still to be looked at."""
        looked = self.memory.looked.get(asr.id, [])
        # Called every control step: the answer only changes with the boundary or what was looked at.
        key = (asr.id, shape_key(asr), tuple(asr.edges), len(looked))
        if self._pending_key == key:
            return list(self._pending)
        seen = np.array(looked, dtype=float).reshape(-1, 2)
        out = []
        for m in unknown_regions(asr, self.p.min_unknown, self.p.region_length):
            if len(seen) and np.hypot(*(seen - m).T).min() < self.p.visit_radius:
                continue
            out.append(m)
        self._pending_key, self._pending = key, out
        return list(out)

    def explored(self, view: MapView, asr: ASR, ex: Exit, edges: dict | None = None) -> bool:
        """Whether exit ``ex`` of ``asr`` needs no visit (see :mod:`service.explore`)."""
        if ex.to is not None or self._failed(asr, ex) or ex.width < self.p.min_exit_width:
            return True
        edges = link_edges(view) if edges is None else edges
        if (asr.id, ex.id) in edges:
            return True
        if self._known_beyond(view, asr, ex):
            return True
        orig = view.asrs.get(asr.duplicate_of) if asr.duplicate_of is not None else None
        if orig is not None:
            mid = transform_points(asr.origin, np.array([ex.midpoint]))[0]
            for other in orig.exits:
                if other.to is None and not self._failed(orig, other) and (orig.id, other.id) not in edges:
                    continue
                omid = transform_points(orig.origin, np.array([other.midpoint]))[0]
                if np.hypot(*(omid - mid)) < self.p.duplicate_radius:
                    return True
        return False

    def _geometry(self, asr: ASR, ex: Exit) -> tuple[np.ndarray, float]:
        """``exit_normal`` and ``depth_beyond`` of ``ex`` (cached while the ASR's boundary stays)."""
        key = (asr.id, shape_key(asr), ex.id, ex.a, ex.b)
        got = self._geometry_cache.get(key)
        if got is None:
            if len(self._geometry_cache) > 4096:
                self._geometry_cache.clear()
            n = exit_normal(asr, ex)
            got = (n, depth_beyond(asr, np.asarray(ex.midpoint, dtype=float), n))
            self._geometry_cache[key] = got
        return got

    def _known_beyond(self, view: MapView, asr: ASR, ex: Exit) -> bool:
        """Whether the space beyond ``ex`` is inside ASRs other than ``asr`` (see ``known_depths``);
        cached while the ASRs stay the same."""
        if not self.p.known_depths:
            return False
        self._known_areas(view)
        key = (self._known_key, asr.id, ex.id, ex.a, ex.b)
        if self._beyond_key != self._known_key:
            self._beyond_key, self._beyond = self._known_key, {}
        if key not in self._beyond:
            self._beyond[key] = self._known_beyond_now(view, asr, ex)
        return self._beyond[key]

    def _probe_points(self, asr: ASR, ex: Exit) -> np.ndarray:
        """The points ``known_depths`` beyond ``ex`` (beyond the ASR polygon, on the exit's
        normal), global frame (m)."""
        n, depth = self._geometry(asr, ex)
        mid = np.asarray(ex.midpoint, dtype=float)
        return transform_points(asr.origin, np.array([mid + (depth + d) * n for d in self.p.known_depths]))

    def _known_beyond_now(self, view: MapView, asr: ASR, ex: Exit) -> bool:
        n, depth = self._geometry(asr, ex)
        pts = self._probe_points(asr, ex)
        for other in self._known_areas(view):
            if other[0] == asr.id:
                continue
            inside = shapely.contains_xy(other[1], pts[:, 0], pts[:, 1])
            pts = pts[~inside]
            if not len(pts):
                return True
        if self.p.known_cover > 1.0:
            return False
        a, b = np.asarray(ex.a, dtype=float) + depth * n, np.asarray(ex.b, dtype=float) + depth * n
        far = max(self.p.known_depths) * n
        strip = shapely.Polygon(transform_points(asr.origin, np.array([a, b, b + far, a + far])))
        if strip.area <= 0.0:
            return False
        return self._covered_by_others(view, asr.id, strip)

    def _covered_by_others(self, view: MapView, asr_id: int, shape: shapely.Geometry) -> bool:
        """Whether at least ``known_cover`` of ``shape`` (global frame) lies inside the polygons of
        ASRs other than ``asr_id``."""
        others = [g for i, g in self._known_polygons(view) if i != asr_id and g.intersects(shape)]
        if not others:
            return False
        return shape.intersection(shapely.union_all(others)).area >= self.p.known_cover * shape.area

    def _known_polygons(self, view: MapView) -> list[tuple[int, shapely.Geometry]]:
        """Every ASR's polygon in the global frame, as it is (cached like :meth:`_known_areas`)."""
        self._known_areas(view)
        return self._polygons

    def _known_areas(self, view: MapView) -> list[tuple[int, shapely.Geometry]]:
        """Every ASR's polygon in the global frame, shrunk by ``known_margin`` (cached while the ASRs'
        boundaries and origins stay the same)."""
        key = tuple((a.id, shape_key(a), tuple(a.origin)) for a in view.asrs.values())
        if self._known_key != key:
            areas, polygons = [], []
            for a in view.asrs.values():
                if len(a.boundary) < 3:
                    continue
                ring = transform_points(a.origin, np.asarray(a.boundary))
                whole = shapely.make_valid(shapely.Polygon(ring))
                polygons.append((a.id, whole))
                poly = whole.buffer(-self.p.known_margin)
                if not poly.is_empty:
                    shapely.prepare(poly)
                    areas.append((a.id, poly))
            self._known_key, self._known, self._polygons = key, areas, polygons
        return self._known

    def unexplored_exits(self, view: MapView, asr: ASR, edges: dict | None = None) -> list[Exit]:
        """Unexplored exits of ``asr``, widest first."""
        edges = link_edges(view) if edges is None else edges
        todo = [e for e in [*asr.exits, *self._side_openings(asr, edges)]
                if not self.explored(view, asr, e, edges)]
        return sorted(todo, key=lambda e: -e.width)

    def _side_openings(self, asr: ASR, edges: dict) -> list[Exit]:
        """The side openings (:func:`side_openings`) of ``asr``'s linked exits, in the last round."""
        if not self.memory.side_round:
            return []
        return [s for e in asr.exits if e.to is not None or (asr.id, e.id) in edges
                for s in side_openings(asr, e, self.p)]

    # -- the decision --------------------------------------------------------------------------
    def plan(self, view: MapView) -> Goal:
        """The next :class:`Goal` in ``view`` (targets in the current ASR's frame, m); the order of
        the choices is :mod:`service.explore`'s."""
        if view.current is None or view.current not in view.asrs:
            return Goal("wait")
        asr = view.asrs[view.current]
        here = (view.pose[0], view.pose[1])
        free = free_space(asr, self.p.clearance)
        self.retire_known_unknown(view, asr)
        pending = self.pending_unknown(asr)
        if pending:
            m = min(pending, key=lambda q: math.hypot(q[0] - here[0], q[1] - here[1]))
            return Goal("unknown", asr.id, target=inside_point(free, m, here), look_at=m)
        edges = link_edges(view)
        exits = self.unexplored_exits(view, asr, edges)
        if exits:
            return self._through(view, asr, exits[0], "exit", free, (asr.id,))
        closing = self.closing_exit(view, asr, edges)
        if closing is not None:
            log.info("exploration: crossing exit %s of ASR %s into known space to close a loop",
                     closing.id, asr.id)
            return self._through(view, asr, closing, "close", free, (asr.id,))
        path = self.backtrack_path(view)
        if path is None:
            far = self._goto(view, asr, free)
            if far is not None:
                return far
            if self.memory.failed_exits and self.memory.retries < self.p.retries:
                # Nothing left but what failed: failures are often passing (a pose estimate that
                # recovered, a jam), so forget them and try again, a bounded number of times.
                self.memory.retries += 1
                log.info("exploration: retrying %d exits that failed (round %d of %d)",
                         len(self.memory.failed_exits), self.memory.retries, self.p.retries)
                self._forget_failures()
                return self.plan(view)
            if self.start_visiting() or self.start_side_round(view):
                return self.plan(view)
            return Goal("done", asr.id)
        hops, exit_id = path
        ex = exit_of(view, asr, exit_id, self.p)
        return self._through(view, asr, ex, "backtrack", free, hops)

    def closing_exit(self, view: MapView, asr: ASR, edges: dict | None = None) -> Exit | None:
        """The widest exit of ``asr`` to cross to close a loop (``ExploreParams.close_loops``), or
        None. The exit has no link, is wide enough and has not failed; the space beyond it is
        known (``known_depths``) and held by no ASR within ``close_min_hops`` - 1 links of ``asr``
        (nor their duplicates). None from a duplicate, from an ASR that made ``close_per_asr``
        such crossings, or from one such a crossing made ``close_chain`` deep
        (``Memory.closing_from``, ``closing_made``)."""
        mem = self.memory
        if (not self.p.close_loops or asr.duplicate_of is not None
                or mem.closing_from.get(asr.id, 0) >= self.p.close_per_asr
                or mem.closing_made.get(asr.id, 0) >= self.p.close_chain):
            return None
        edges = link_edges(view) if edges is None else edges
        related = within_hops(edges, asr.id, self.p.close_min_hops - 1)
        for ex in sorted(asr.exits, key=lambda e: -e.width):
            if (ex.to is not None or (asr.id, ex.id) in edges or ex.width < self.p.min_exit_width
                    or self._failed(asr, ex)):
                continue
            if not self._known_beyond(view, asr, ex):
                continue
            owners = self._owners_beyond(view, asr, ex)
            near = any(o in related or view.asrs[o].duplicate_of in related for o in owners)
            if owners and not near:
                return ex
        return None

    def _owners_beyond(self, view: MapView, asr: ASR, ex: Exit) -> set[int]:
        """The ASRs other than ``asr`` whose polygons (global frame, shrunk by ``known_margin``)
        hold a point of the probe line beyond ``ex`` (``known_depths``)."""
        pts = self._probe_points(asr, ex)
        return {i for i, g in self._known_areas(view)
                if i != asr.id and shapely.contains_xy(g, pts[:, 0], pts[:, 1]).any()}

    def _goto(self, view: MapView, asr: ASR, free) -> Goal | None:
        """No way through the topological map to an unexplored exit (the way out of this ASR
        failed): head for the nearest unexplored exit of any ASR (global frame) across this ASR,
        leaving it wherever the mapper sees it leave, and plan again from the next ASR."""
        edges = link_edges(view)
        here = transform_points(asr.origin, np.array([view.pose[:2]]))[0]
        best, best_d = None, math.inf
        for other in view.asrs.values():
            if other.id == asr.id:
                continue
            for ex in self.unexplored_exits(view, other, edges):
                mid = transform_points(other.origin, np.array([ex.midpoint]))[0]
                d = float(np.hypot(*(mid - here)))
                if d < best_d:
                    best, best_d = (other, ex), d
        if best is None:
            return None
        other, ex = best
        ends = np.array(crossing(other, ex, self.p))
        stage, through = transform_points(compose(inverse(asr.origin), other.origin), ends).tolist()
        # The staging point as it is, in the other ASR: the way there is planned through the map.
        return Goal("goto", asr.id, target=(stage[0], stage[1]), exit=ex.id,
                    through=(through[0], through[1]), path=(asr.id, other.id), exit_mid=ex.midpoint)

    def _through(self, view, asr: ASR, ex: Exit, kind: str, free, path) -> Goal:
        s, t = crossing(asr, ex, self.p)
        stage = (float(s[0]), float(s[1]))
        through = (float(t[0]), float(t[1]))
        here = (view.pose[0], view.pose[1])
        return Goal(kind, asr.id, target=inside_point(free, stage, here), exit=ex.id,  # type: ignore[arg-type]
                    through=through, path=tuple(path), exit_mid=ex.midpoint)  # type: ignore[arg-type]

    def backtrack_path(self, view: MapView) -> tuple[tuple[int, ...], str] | None:
        """Shortest route (metres between global centres) from the current ASR to the nearest ASR
        with an unexplored exit: (ASR ids along it, the exit of the current ASR to take), or None."""
        edges = link_edges(view, borrow=True)
        plain = link_edges(view)
        out: dict[int, list[tuple[str, int]]] = {}
        for (a, e), b in edges.items():
            if a in view.asrs and b in view.asrs and (a, e) not in self.memory.failed_exits \
                    and exit_of(view, view.asrs[a], e) is not None:
                out.setdefault(a, []).append((e, b))
        start = view.current
        dist = {start: 0.0}
        prev: dict[int, tuple[int, str]] = {}
        todo = [(0.0, start)]
        done: set[int] = set()
        while todo:
            d, a = heapq.heappop(todo)
            if a in done:
                continue
            done.add(a)
            if a != start and (self.unexplored_exits(view, view.asrs[a], plain)
                               or (self.memory.visiting and self.pending_unknown(view.asrs[a]))):
                hops = [a]
                while hops[-1] != start:
                    hops.append(prev[hops[-1]][0])
                hops.reverse()
                first_exit = prev[hops[1]][1]
                return tuple(hops), first_exit
            for e, b in out.get(a, ()):
                nd = d + centre_distance(view.asrs[a], view.asrs[b])
                if nd < dist.get(b, math.inf):
                    dist[b] = nd
                    prev[b] = (a, e)
                    heapq.heappush(todo, (nd, b))
        return None
