"""The mapper: readings in, ASRs and events out (method.md §1-4). Pure computation, no I/O.

``Mapper(params)`` takes :class:`~mapper.types.Odometry` (odometry frame) and
:class:`~mapper.types.Scan` (laser frame) readings. The pose at a scan is the odometry
interpolated at ``scan.t``; its increment since the previous scan is predicted and corrected in
the current ASR's frame (:mod:`mapper.localise`). Every ``view_spacing`` metres or ``view_turn``
radians the scan becomes a viewpoint: surfaces (:mod:`mapper.lines`), exits and the truncated view
(:mod:`mapper.exits`, :mod:`mapper.view`) are computed and unioned into the ASR
(:mod:`mapper.asr_builder`); scans in between only localise, which bounds the per-scan cost
(nearby views add almost no area).

Frames: the first ASR's frame is the global frame (origin (0, 0, 0)); each ASR's frame is the
robot pose at the scan that created it; ``pose`` is the robot in the current ASR's frame and
``global_pose`` = origin(current) ⊕ pose.

Crossing (§4): when the segment from the previous to the current pose crosses an exit of the
current ASR and the current pose lies outside its polygon, the robot leaves through it. If the
topological map knows where that exit leads (:mod:`mapper.topology`), the robot **re-enters** that
ASR: its pose is handed over with the transition's relative pose, localisation continues against
that ASR's reference scans, and its polygon keeps growing. Otherwise a new ASR is created with its
frame at the current pose and global origin = old origin ⊕ pose; its exit nearest the crossing point
is the entrance (``via``). Right after entering through an exit, crossing that same exit back does
not count until the robot has been ``CycleParams.entry_hysteresis`` away from it (a robot standing in
a doorway would otherwise flip between the two ASRs).

**Pipelining (better than doing a viewpoint's work in one scan):** a viewpoint's work runs in
stages over two or three scans, so that no scan carries all of it. The viewpoint scan refines its
pose, takes its points as a localisation reference, and computes as many of the view's stages
(surfaces, exits, view polygon: ``_ViewWork``) as fit before its own time reaches ``_AHEAD``,
judged by each stage's recent cost; the next ``add_scan`` starts by computing the rest and unioning
the view into the ASR's polygon and label store (:meth:`AsrBuilder.add_view` with
``relabel=False``); the last stage, relabelling the boundary (exits, centre), then ``AsrUpdated``
and the cycle check, ends the first scan from then on that has time to spare (``_SPARE``: usually
the one after). A stage runs earlier whenever something needs its
result: the exits when the robot is outside the polygon or near the exit it came in by, everything
before leaving the ASR or taking the next view, and everything when ``asrs``, ``globalmap``,
``global_pose``, ``document()`` or ``viewpoints()`` is read. Each stage sees the state it would
have seen had the view been done at once, so the map is the same (when a stage runs depends on
the clock, what it computes does not); a view's ``AsrUpdated`` and cycle events come a scan or two
later (``flush()`` returns the last ones after the last scan).
A scan that creates an ASR computes its first view; the union, relabelling, entrance and cycle
check of the new ASR are the next scan's first stage (``ExitCrossed`` comes with it).
``Mapper(params, defer_views=True)`` pipelines (offline replay and ``asrmap bench mapper`` do); the
default does all of a viewpoint's work in its own scan, as the live service and the simulator do:
there the explorer reads the map after every scan, and the odometry a scan gets depends on when it
is processed, so the service keeps its timing as it was.

The global metric map and cycle closing (§5, §7) live in :class:`mapper.globalmap.GlobalMap`
(``Mapper.globalmap``): it is told of every new, re-entered and grown ASR and answers with cycle
events (CycleDetected, CycleRejected, MapRealigned). ``document()`` gives the ``asrmap/map/1`` map and
``Mapper.from_document`` continues a saved one.
"""

from __future__ import annotations

import bisect
import gc
import math
import struct
import time

import numpy as np
import shapely

from mapper.asr_builder import AsrBuilder
from mapper.document import document_of, load_globalmap
from mapper.events import AsrCreated, AsrUpdated, Event, ExitCrossed
from mapper.exits import find_covers, segment_distance
from mapper.globalmap import GlobalMap
from mapper.lines import ScanPoints, extract_surfaces, scan_points
from mapper.localise import Localiser
from mapper.params import MapperParams
from mapper.se2 import Pose, between, compose, interpolate, inverse, transform_points
from mapper.topology import Transition
from mapper.types import ASR, Exit, Odometry, Scan
from mapper.view import View, build_view
from mapper.warmup import warm_up

_ODOM_KEEP = 4096  # odometry readings kept for interpolation (minutes at 20 Hz)
#: s. Pipelined, a scan that has spent less than this relabels the ASR its union grew (a view's
#: last stage) before returning; a busier scan leaves it to the next one with time to spare.
_SPARE = 1.5e-3
#: s. Pipelined, a viewpoint scan computes as many of its view's stages (surfaces, exits, polygon)
#: as fit before its own time reaches this, judged by each stage's recent cost (after relabelling
#: the view before, if still waiting); the next scan computes the rest before the union.
_AHEAD = 2.6e-3
_STAGES = ("extract", "exits", "view")


class _ViewWork:
    """A waiting view's stages as far as they are computed (robot frame): surfaces, covers, view.

    Each is a pure function of the scan and the parameters, so which scan computes it changes
    nothing but the time it is spent in."""

    __slots__ = ("covers", "pts", "surf", "view")

    def __init__(self, pts: ScanPoints):
        self.pts, self.surf, self.covers, self.view = pts, None, None, None

    def step(self, p: MapperParams) -> tuple[str, float] | None:
        """Compute the next stage; its name and time (s), or None when the view is done."""
        stage = self.next_stage()
        tic = time.perf_counter()
        if stage == "extract":
            self.surf = extract_surfaces(self.pts, p)
        elif stage == "exits":
            self.covers = find_covers(self.surf, p)
        elif stage == "view":
            self.view = build_view(self.surf, p, self.covers)
        else:
            return None
        return stage, time.perf_counter() - tic

    def next_stage(self) -> str | None:
        """The stage :meth:`step` would compute next (None: done)."""
        for stage, done in zip(_STAGES, (self.surf, self.covers, self.view), strict=True):
            if done is None:
                return stage
        return None


def _segments(exits: list[Exit]) -> np.ndarray:
    """The exits' segments (E, 2, 2), their ASR's frame (m)."""
    return np.array([[e.a, e.b] for e in exits], dtype=float)


def _outward_x(e: Exit) -> float:
    """x of the unit normal on the outside of exit ``e`` (right of a -> b, the ASR boundary being
    counter-clockwise), in its ASR's frame: +1 faces ahead of a robot at the origin, -1 behind."""
    d = np.subtract(e.b, e.a)
    return float(d[1] / max(float(np.hypot(*d)), 1e-12))


def entrance(exits: list[Exit], at: tuple[float, float], passage_width: float) -> Exit | None:
    """Of a new ASR's ``exits``, the one the robot came in through, crossing at ``at`` (the ASR's
    frame, m; the robot at its origin facing +x): the nearest within two ``passage_width`` of
    ``at`` that neither faces ahead nor lies beside the crossing; None if there is none.

    The robot came in from behind (the frame's -x): an exit whose outside lies ahead of it
    (right of a -> b, towards +x) is the way on, not the way in. A first view taken on the
    doorway is a sliver whose only exit is its front edge; taken as the entrance, its crossing
    was ignored as the robot walked on (entry hysteresis) and its gate kept every later view
    from growing the ASR ahead: in the Intel log the robot stayed in a 0.1 m² ASR for 2700 scans.

    An exit wider than three passages whose chord, prolonged, passes the crossing point more than
    a passage width beyond its end (:func:`_beside`) is an occlusion seen past the corner, not
    the doorway: ``lab`` seed 1 came round the corner into the south-west of the corridor, and
    the first view's only exit ran 7.2 m diagonally to the far end of the south corridor, one
    end 0.8 m from where the robot came in. Taken as the entrance (linked back), it made the south
    corridor look explored and took the gate from the way back: the corridor's ASR grew up the
    west corridor, the robot could not leave it the way it came, and 3 of 7 regions were never
    entered. Narrower exits are left alone: a doorway beside the path (README, known faults)
    would need the test of every exit (with 0.3 m of slack), which changed 11 of Intel corrected's
    77 entrances and closed a false pair there."""
    wide = 3.0 * passage_width
    exits = [e for e in exits if _outward_x(e) <= 0.5 and not _beside(e, at, wide, passage_width)]
    if not exits:
        return None
    d = segment_distance(at[0], at[1], _segments(exits))
    k = int(np.argmin(d))  # the first of equals, as before
    return exits[k] if d[k] < 2.0 * passage_width else None


def _beside(e: Exit, at: tuple[float, float], wide: float, slack: float) -> bool:
    """Whether exit ``e``, wider than ``wide`` (m), lies beside the point ``at`` rather than across
    it: the foot of ``at`` on the chord's line falls more than ``slack`` (m) beyond either end (one
    frame)."""
    length = e.width
    if length <= wide:
        return False
    s = float(np.dot(np.subtract(at, e.a), np.subtract(e.b, e.a))) / length
    return s < -slack or s > length + slack


def _segments_cross(p0, p1, a, b) -> tuple[bool, tuple[float, float]]:
    """Whether segment p0-p1 crosses segment a-b, and where (m)."""
    r = (p1[0] - p0[0], p1[1] - p0[1])
    s = (b[0] - a[0], b[1] - a[1])
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-12:
        return False, (0.0, 0.0)
    qp = (a[0] - p0[0], a[1] - p0[1])
    t = (qp[0] * s[1] - qp[1] * s[0]) / den
    u = (qp[0] * r[1] - qp[1] * r[0]) / den
    if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
        return True, (p0[0] + t * r[0], p0[1] + t * r[1])
    return False, (0.0, 0.0)


_warm = False


def _warm_up() -> None:
    """:func:`mapper.warmup.warm_up`, once per process (the mappers it makes skip it); then every
    object alive is moved out of the garbage collector's reach (``gc.freeze``): numba's compiler
    leaves so many long-lived objects that one full collection over them took 75 ms, inside a scan
    (Intel replay). They live as long as the process anyway."""
    global _warm
    if not _warm:
        _warm = True
        warm_up()
        gc.collect()
        gc.freeze()


class Mapper:
    """ASRs from odometry and laser scans; see the module docstring.

    ``asrs``: id -> :class:`~mapper.types.ASR`; ``current``: id of the ASR the robot is in (None
    before the first scan); ``pose``: robot pose in the current ASR frame; ``global_pose``: in the
    global frame; ``timing``: seconds spent per stage on the last scan (for benchmarks).

    The first mapper made in a process compiles the mapper's kernels (:mod:`mapper.warmup`): about
    0.3-1.5 s with numba's disk cache, about 10 s the first time on a machine, here rather than
    inside the first scans.
    """

    def __init__(self, params: MapperParams | None = None, defer_views: bool = False):
        _warm_up()
        self.params = params or MapperParams()
        self.defer_views = defer_views
        self._asrs: dict[int, ASR] = {}
        self.current: int | None = None
        self.localiser = Localiser(self.params)
        self.timing: dict[str, float] = {}
        self._builders: dict[int, AsrBuilder] = {}
        self._frozen: dict[int, shapely.Geometry] = {}  # matched ASRs: their polygon when first matched
        # Per ASR: the area its growth is clipped to (_clip_closed_growth, ASR frame) and what it was
        # made from (the match's placement and boundary, or the frozen polygon, which never changes):
        # the same buffer is not recomputed for every view while neither changes.
        self._clip_areas: dict[int, tuple[tuple, shapely.Geometry]] = {}
        self._odom_t: list[float] = []
        self._odom_pose: list[Pose] = []
        self._last_odom: Pose | None = None
        self._last_view: Pose | None = None
        self._next_id = 1
        self._gm = GlobalMap(self.params.cycles)
        # A viewpoint's view waiting to be unioned into its ASR (see "Pipelining" in the module
        # docstring): (time, ASR id, pose, the view or its stages so far, walked); and the events of
        # settled views not yet returned.
        self._pending: tuple[float, int, Pose, View | _ViewWork, bool] | None = None
        # s: each stage's recent cost (for _work_ahead)
        self._cost = {"extract": 6e-4, "exits": 6e-4, "view": 3e-4}
        self._stale: tuple[float, int] | None = None  # (time, ASR) unioned but not yet relabelled
        self._creating: tuple | None = None  # the ASR the last scan created: (t, old, exit, at, pose)
        self._outbox: list[Event] = []
        self._scan_start = 0.0  # perf_counter() at the start of the current add_scan
        # Per ASR: (scan points in the robot frame, viewpoint pose) of its first and latest views,
        # to restore the localisation reference when the robot re-enters it.
        self._refs: dict[int, list[tuple[np.ndarray, Pose]]] = {}
        self._loc_refs: dict[int, dict] = {}  # per ASR: the localiser's reference as the robot left it
        # The (ASR, exit) the robot last came in through, and whether it has moved far enough
        # from it for a crossing of that exit to count again.
        self._entry: tuple[int, str | None] | None = None
        self._armed = True
        # Where (current ASR frame) the robot came into the current ASR, and whether it has been
        # inside its polygon since (see _may_leave_elsewhere).
        self._entered_at: tuple[float, float] | None = None
        self._been_inside = True
        # After from_document: the ASR and pose (its frame) the robot is assumed to restart at.
        self._resume: tuple[int, Pose] | None = None

    # --- the map document ----------------------------------------------------------------------
    def document(self, robot: str = "pioneer") -> dict:
        """The whole map as an ``asrmap/map/1`` document (:mod:`mapper.document`)."""
        return document_of(self.globalmap, robot)

    @property
    def asrs(self) -> dict[int, ASR]:
        """id -> ASR, with every view taken so far unioned in."""
        self._settle()
        return self._asrs

    @property
    def globalmap(self) -> GlobalMap:
        """The global metric map (:class:`~mapper.globalmap.GlobalMap`), every view unioned in."""
        self._settle()
        return self._gm

    def flush(self) -> list[Event]:
        """Union the view still waiting (if any) and return the events not yet returned by
        :meth:`add_scan`: call it after the last scan (replay's end, shutdown)."""
        self._settle()
        out, self._outbox = self._outbox, []
        return out

    @classmethod
    def from_document(
        cls, doc: dict, params: MapperParams | None = None, pose: Pose = (0.0, 0.0, 0.0)
    ) -> Mapper:
        """A mapper continuing a saved map. The robot is assumed to restart at ``pose`` in the frame
        of the document's last ASR: its first scan starts a new ASR there, which the cycle check
        then relates to the saved map (usually as a duplicate of the ASR it stands in). Saved ASRs
        keep their records but not their views, so they are matched, not re-entered."""
        m = cls(params)
        m._gm = load_globalmap(doc, m.params.cycles)
        m._asrs = dict(m._gm.asrs)
        m._next_id = max(m._asrs, default=0) + 1
        if m._gm.current is not None:
            m._resume = (m._gm.current, tuple(pose))
        m._gm.current = None
        return m

    # --- poses -------------------------------------------------------------------------------------
    @property
    def pose(self) -> Pose:
        """Robot pose in the current ASR's frame (m, m, rad)."""
        return self.localiser.pose

    @property
    def global_pose(self) -> Pose:
        """Robot pose in the global frame (m, m, rad): origin(current) ⊕ pose."""
        if self.current is None:
            return (0.0, 0.0, 0.0)
        return compose(self.asrs[self.current].origin, self.pose)

    def viewpoints(self, asr: int) -> list[Pose]:
        """The poses (that ASR's frame) from which ASR ``asr``'s views were taken."""
        self._settle()
        return list(self._builders[asr].viewpoints)

    # --- inputs ------------------------------------------------------------------------------------
    def add_odometry(self, odo: Odometry) -> list[Event]:
        """Record an odometry reading (odometry frame); returns no events."""
        if self._odom_t and odo.t < self._odom_t[-1]:
            i = bisect.bisect_right(self._odom_t, odo.t)
            self._odom_t.insert(i, odo.t)
            self._odom_pose.insert(i, odo.pose)
        else:
            self._odom_t.append(odo.t)
            self._odom_pose.append(odo.pose)
        if len(self._odom_t) > 2 * _ODOM_KEEP:
            del self._odom_t[:_ODOM_KEEP], self._odom_pose[:_ODOM_KEEP]
        return []

    def odometry_at(self, t: float) -> Pose | None:
        """Odometry pose interpolated at time t (s); held at the ends of the record; None if empty."""
        ts = self._odom_t
        if not ts:
            return None
        i = bisect.bisect_left(ts, t)
        if i <= 0:
            return self._odom_pose[0]
        if i >= len(ts):
            return self._odom_pose[-1]
        t0, t1 = ts[i - 1], ts[i]
        f = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return interpolate(self._odom_pose[i - 1], self._odom_pose[i], f)

    def add_scan(self, scan: Scan) -> list[Event]:
        """Localise, grow the current ASR and detect exit crossings; returns the events (those of
        the previous viewpoint's view first, see "Pipelining" in the module docstring)."""
        start = self._scan_start = time.perf_counter()
        self.timing = {}
        if self._pending is not None:
            self._settle_labels()  # the union needs the labels (gates) of the view before
        self._settle_view()
        self._settle_creation()
        own = self._scan(scan)
        if self._stale is not None and time.perf_counter() - start < _SPARE:
            self._settle_labels()  # this scan had time to spare
        out, self._outbox = self._outbox, []
        return out + own if out else own

    def _scan(self, scan: Scan) -> list[Event]:
        tic = time.perf_counter()
        odo = self.odometry_at(scan.t)
        if odo is None:
            odo = self._last_odom or (0.0, 0.0, 0.0)
        pts = scan_points(scan, self.params)
        timing = self.timing
        timing["points"] = time.perf_counter() - tic
        if self.current is None:
            self._last_odom = odo
            origin: Pose = (0.0, 0.0, 0.0)
            if self._resume is not None:
                origin = compose(self._asrs[self._resume[0]].origin, self._resume[1])
            return self._new_asr(scan.t, origin, None, pts)
        delta = between(self._last_odom, odo)
        self._last_odom = odo
        prev = self.pose
        tic = time.perf_counter()
        self.localiser.predict(delta)
        self.localiser.correct(pts.xy)
        pose = self.pose
        timing["localise"] = time.perf_counter() - tic
        # inside the polygon the robot neither crossed an exit nor left elsewhere (distance 0)
        inside = bool(shapely.contains_xy(self._builders[self.current].polygon, pose[0], pose[1]))
        if inside:
            self._been_inside = True
        crossed = self._crossed_exit(prev, pose, inside)
        if crossed is not None:
            self._builders[self.current].crossed.add(crossed[0].id)
        if crossed is None and not inside and self._may_leave_elsewhere(pose):
            crossed = self._left_elsewhere(prev, pose)
        if crossed is not None:
            events = self._leave_through(scan.t, crossed[0], crossed[1], pose, pts)
            self._entered_at, self._been_inside = self.pose[:2], False
            return events
        if self._is_viewpoint(pose):
            tic = time.perf_counter()
            self.localiser.refine(pts.xy)  # a viewpoint's pose is inherited by the reference
            timing["refine"] = time.perf_counter() - tic
            # pipelined, the view's stages are computed as this scan has time, the rest next scan
            return self._add_view(scan.t, pts, self.pose, late=True, walked=True)
        return []

    # --- growing the current ASR -----------------------------------------------------------------
    def _is_viewpoint(self, pose: Pose) -> bool:
        last = self._last_view
        if last is None:
            return True
        p = self.params
        return (
            math.hypot(pose[0] - last[0], pose[1] - last[1]) >= p.view_spacing
            or abs(math.remainder(pose[2] - last[2], 2.0 * math.pi)) >= p.view_turn
        )

    def _add_view(
        self, t: float, pts: ScanPoints, pose: Pose, defer: bool = True, late: bool = False,
        walked: bool = False,
    ) -> list[Event]:
        """Take this scan as a view of the current ASR from ``pose``: now, or pipelined (``defer``;
        ``late``: even its surfaces, exits and view wait for the next scan). ``walked``: a view on
        the way (not an ASR's first, nor a re-entry's), which is not unioned when taken standing in
        a doorway (:meth:`_at_exit`)."""
        p = self.params
        pipelined = defer and self.defer_views
        now = not (late and pipelined)  # else the view, and whether it may be unioned, wait
        at_exit = now and walked and self._at_exit(self.current, pose)  # not unioned: no view needed
        view = self._view(pts) if now and not at_exit else _ViewWork(pts)
        self.localiser.add_reference(pts.xy, pose)
        refs = self._refs.setdefault(self.current, [])
        refs.append((pts.xy, pose))
        if len(refs) > p.reference_scans + 1:
            del refs[1]  # the first view anchors the frame, as in the localiser
        self._last_view = pose
        if at_exit or (walked and isinstance(view, View) and view.in_doorway):
            return []
        self._pending = (t, self.current, pose, view, walked)
        if pipelined:
            self._work_ahead()
            return []
        before = len(self._outbox)  # events of earlier views stay in the outbox
        self._settle()
        out, self._outbox = self._outbox[before:], self._outbox[:before]
        return out

    def _at_exit(self, aid: int, pose: Pose) -> bool:
        """Whether the robot centre (``pose``, ASR ``aid``'s frame) lies within ``rear_closure`` of
        one of ``aid``'s exits: standing in a doorway, where a view on the way is not unioned.

        It is one of two tests for that: this, or the scan's own
        cover of a gap running through the robot (``View.in_doorway``; at the doorway's line the
        jambs are beside or behind the laser and the scan may show no gap at all, hence both).
        From a doorway the view sees into the space beyond, unbounded. In the simulated office
        (seed 2) such a view, 3 cm before the doorway into room 3, grew the corridor's ASR over the
        room; the robot never crossed out of it, and exploration ended with 4 of 6 rooms unseen. A
        view later the robot is past the doorway: inside, the view is unioned; outside, it has
        crossed. The view still joins the localisation reference (postponing the whole viewpoint
        instead, refinement included, raised Intel raw's ASR frame error from 1.1 to 1.8 m). An
        ASR's first view and a re-entry's are taken in the doorway by definition, and unioned."""
        exits = self._asrs[aid].exits
        return bool(exits) and bool(
            np.min(segment_distance(pose[0], pose[1], _segments(exits))) < self.params.rear_closure
        )

    def _view(self, pts: ScanPoints | _ViewWork) -> View:
        """Surfaces, exits and the truncated view of one scan (robot frame), or the rest of them."""
        work = pts if isinstance(pts, _ViewWork) else _ViewWork(pts)
        while self._step(work):
            pass
        return work.view

    def _step(self, work: _ViewWork) -> bool:
        """One stage of ``work`` (False: none left), timed into ``timing`` and the stage's cost."""
        done = work.step(self.params)
        if done is None:
            return False
        stage, dt = done
        self.timing[stage] = dt
        self._cost[stage] += 0.2 * (dt - self._cost[stage])
        return True

    def _work_ahead(self) -> None:
        """Compute the waiting view's stages while each fits before ``_AHEAD`` (see ``_ViewWork``),
        after the relabelling its union will need (the view before's, if still waiting)."""
        if self._pending is None or not isinstance(self._pending[3], _ViewWork):
            return
        work = self._pending[3]
        # The union of this view needs the labels of the view before: still waiting, they are done
        # here whatever the time, since the next scan would do them first, before this view's rest
        # and union (one scan carrying relabelling, view and union: 4 ms).
        self._settle_labels()
        while (stage := work.next_stage()) is not None:
            if time.perf_counter() - self._scan_start + self._cost[stage] > _AHEAD:
                return
            self._step(work)

    def _settle(self) -> None:
        """Finish every stage of the views still waiting; their events go to the outbox."""
        self._settle_labels()
        self._settle_view()
        self._settle_creation()
        self._settle_labels()

    def _settle_creation(self) -> None:
        """Finish entering the ASR created by the last scan: relabel its first view (whose
        ``AsrUpdated`` is not reported, as when done at once), then :meth:`_entered_new`."""
        if self._creating is None:
            return
        t, old, e, at, pose = self._creating
        self._creating = None
        tic = time.perf_counter()
        self._stale = None
        self._builders[self.current].ensure_labels()
        self.timing["labels"] = time.perf_counter() - tic
        self._outbox += self._entered_new(t, old, e, at, pose)

    def _settle_view(self) -> None:
        """Union the waiting view into its ASR (its relabelling then waits, when deferring)."""
        if self._pending is None:
            return
        t, aid, pose, view, walked = self._pending
        self._pending = None
        if isinstance(view, _ViewWork):
            if walked and self._at_exit(aid, pose):
                return
            view = self._view(view)
            if walked and view.in_doorway:
                return
        tic = time.perf_counter()
        builder = self._builders[aid]
        before = builder.polygon
        changed = builder.add_view(view, pose, relabel=False)
        if changed:
            self._keep_closed_places(builder, before, pose)
            self._stale = (t, aid)
        self.timing["asr"] = time.perf_counter() - tic
        if changed and not self.defer_views:
            self._settle_labels()

    def _settle_labels(self) -> None:
        """Relabel the ASR the last union grew, then its AsrUpdated and the cycle check."""
        if self._stale is None:
            return
        t, aid = self._stale
        self._stale = None
        timing = self.timing
        tic = time.perf_counter()
        builder = self._builders[aid]
        builder.ensure_labels()
        timing["labels"] = time.perf_counter() - tic
        a = builder.asr
        self._outbox.append(AsrUpdated(t, a.id, a.area, a.scans))
        if self._gm.current == a.id:  # not while the ASR is being created
            tic = time.perf_counter()
            self._outbox += self._gm.updated(a.id, t)
            timing["cycles"] = time.perf_counter() - tic

    def _keep_closed_places(self, b: AsrBuilder, before: shapely.Polygon, pose: Pose) -> None:
        """The two ASRs of a closed cycle stay the place they were matched as (method.md §5.5): a
        duplicate does not grow beyond its match's polygon, nor a match beyond its polygon when it
        was first matched (each plus ``duplicate_margin``, in the global frame both are placed in).
        Views through their doorways would otherwise swallow the next room or corridor into one of
        them, which then no longer is the place the closure said; the robot leaves the clipped ASR
        as it leaves any ASR (through an exit, or where it is outside it), into a new one. And
        (:meth:`_hold_closures`) no view may grow either so that its cycle's crosscheck fails."""
        self._clip_closed_growth(b, before, pose)
        self._hold_closures(b, before, pose)

    def _clip_closed_growth(self, b: AsrBuilder, before: shapely.Polygon, pose: Pose) -> None:
        """The duplicate_margin clip of :meth:`_keep_closed_places`."""
        a = b.asr
        match = self._asrs.get(a.duplicate_of) if a.duplicate_of is not None else None
        if match is not None and len(match.boundary) >= 3:
            rel = between(a.origin, match.origin)  # the match's frame seen from the duplicate's
            key: tuple = ("match", struct.pack("3d", *rel), match.boundary.tobytes())
            if (kept := self._clip_areas.get(a.id)) is None or kept[0] != key:
                area = shapely.make_valid(shapely.Polygon(transform_points(rel, match.boundary)))
                kept = self._clip_areas[a.id] = (key, area.buffer(self.params.duplicate_margin))
        elif a.id in self._frozen or any(o.duplicate_of == a.id for o in self._asrs.values()):
            # Not current when it was matched: unchanged since, until this first view back in it.
            area = self._frozen.setdefault(a.id, before)
            if (kept := self._clip_areas.get(a.id)) is None or kept[0] != ("frozen",):
                kept = self._clip_areas[a.id] = (("frozen",), area.buffer(self.params.duplicate_margin))
        else:
            return
        b.clip_growth(before, kept[1], pose[:2])

    def _hold_closures(self, b: AsrBuilder, before: shapely.Polygon, pose: Pose) -> None:
        """``CycleParams.hold_crosscheck``: refuse a view's growth of an ASR of an accepted cycle when
        it would leave a centre less than ``crosscheck_margin`` inside the other polygon and less
        deep than before (:meth:`GlobalMap.closure_depth`); the ASR keeps its polygon of ``before``."""
        c = self.params.cycles
        if not c.hold_crosscheck:
            return
        now = self._gm.closure_depth(b.asr.id, b.polygon)
        if now >= c.crosscheck_margin:
            return
        if before.is_empty or now >= self._gm.closure_depth(b.asr.id, before):
            return
        b.clip_growth(before, before, pose[:2])

    # --- crossing exits (§4): small methods, meant to be extended --------------------------------
    def _crossed_exit(
        self, prev: Pose, pose: Pose, inside: bool | None = None
    ) -> tuple[Exit, tuple[float, float]] | None:
        """The exit of the current ASR crossed between ``prev`` and ``pose`` (ASR frame) and where,
        if the robot now lies outside the ASR polygon (``inside``: whether it lies inside, if known);
        else None."""
        b = self._builders[self.current]
        if not self._armed and self._entry is not None and self._entry[0] == self.current:
            self._settle_labels()  # the entry hysteresis reads the exits
        ignore = self._entry_to_ignore(b, pose)
        if inside is None:
            inside = bool(shapely.contains_xy(b.polygon, pose[0], pose[1]))
        if inside:
            return None
        self._settle_labels()  # outside: the exits are needed, and leaving needs the last check done
        if not b.asr.exits:
            return None
        first = None
        for e in b.asr.exits:
            if e.id == ignore:
                continue
            hit, at = _segments_cross(prev, pose, e.a, e.b)
            if hit:
                # Of exits crossed in one step (an open-plan ASR's chords overlap), the one known to
                # lead somewhere: another would make a new ASR of known space.
                if self._gm.lookup(self.current, e.id) is not None:
                    return e, at
                first = first or (e, at)
        return first

    def _entry_to_ignore(self, b: AsrBuilder, pose: Pose) -> str | None:
        """The id of the exit just entered through while the robot is still near it (hysteresis)."""
        if self._armed or self._entry is None or self._entry[0] != self.current:
            return None
        e = next((x for x in b.asr.exits if x.id == self._entry[1]), None)
        if e is None or shapely.LineString([e.a, e.b]).distance(shapely.Point(pose[:2])) > (
            self.params.cycles.entry_hysteresis
        ):
            self._armed = True
            return None
        return e.id

    def _may_leave_elsewhere(self, pose: Pose) -> bool:
        """Whether the robot, outside the current ASR, may leave it elsewhere than through an exit:
        once it has been inside the polygon since it came in, or has moved ``leave_settle`` from
        where it came in. A pose handed over on re-entry can land outside a drifted ASR, beside
        the exit it came through; leaving at once would bounce it between the two every scan."""
        if self._been_inside or self._entered_at is None:
            return True
        moved = math.hypot(pose[0] - self._entered_at[0], pose[1] - self._entered_at[1])
        return moved > self.params.leave_settle

    def _left_elsewhere(self, prev: Pose, pose: Pose) -> tuple[Exit, tuple[float, float]] | None:
        """When the robot is more than ``leave_margin`` outside the current ASR without having crossed
        one of its exits (it left through an ``unknown`` edge, or where no view showed a gap), the
        exit it took is opened there (:meth:`AsrBuilder.open_exit`); returns it and where, else None."""
        b = self._builders[self.current]
        here = shapely.Point(pose[:2])
        if b.polygon.is_empty or b.polygon.distance(here) <= self.params.leave_margin:
            return None
        ring = b.polygon.exterior
        hit = ring.intersection(shapely.LineString([prev[:2], pose[:2]]))
        if hit.is_empty:
            at = ring.interpolate(ring.project(here))
        else:
            pts = shapely.get_coordinates(hit)
            at = shapely.Point(pts[np.argmin(np.hypot(*(pts - np.asarray(prev[:2])).T))])
        self._settle_labels()
        e = b.open_exit((at.x, at.y))
        return e, (at.x, at.y)

    def _leave_through(
        self, t: float, e: Exit, at: tuple[float, float], pose: Pose, pts: ScanPoints
    ) -> list[Event]:
        """Leave through exit ``e`` (crossed at ``at``): re-enter the ASR it is known to lead to, or
        create the ASR beyond it with its frame at ``pose``."""
        old = self.current
        self._loc_refs[old] = self.localiser.reference()  # for a re-entry into old
        known = self._gm.lookup(old, e.id)
        if known is None:  # a doorway crossed before, whose exit relabelling has renamed
            known = self._gm.relink(old, e.id, at, self.params.passage_width, self._builders)
        if known is not None and known.dst in self._builders:
            return self._reenter(t, known, pose, pts)
        origin = compose(self._asrs[old].origin, pose)
        events = self._new_asr(t, origin, old, pts)
        if self.defer_views:  # the rest once its first view is in, at the start of the next scan
            self._creating = (t, old, e, at, pose)
            return events
        return events + self._entered_new(t, old, e, at, pose)

    def _entered_new(self, t: float, old: int, e: Exit, at: tuple[float, float], pose: Pose) -> list[Event]:
        """The new (current) ASR, its first view in, entered from ``old`` through ``e``: its entrance,
        the transition and the cycle check."""
        new = self.current
        e.to = new
        local_at = between(pose, (at[0], at[1], 0.0))[:2]
        via = self._entrance(new, local_at)
        if via is None:
            via = self._open_entrance(new, local_at)
        if via is not None:
            via.to = old
        via_id = via.id if via is not None else None
        self._entry, self._armed = (new, via_id), False
        events: list[Event] = [ExitCrossed(t, old, e.id, new, via_id, True)]
        tic = time.perf_counter()
        events += self._gm.add_created(self._asrs[new], old, e.id, via_id, pose, t)
        self.timing["cycles"] = time.perf_counter() - tic
        return events

    def _open_entrance(self, asr: int, at: tuple[float, float]) -> Exit | None:
        """The entrance of a new ASR whose first view shows none (the laser looks ahead: the doorway
        just passed is behind the robot), opened where the robot came in (``at``, its frame), so the
        ASR has a way back and its gate keeps later views from growing back through the doorway.

        Only when the first view is a real area and the exit opened faces backwards (its outside,
        right of a -> b, away from the robot's heading, +x): on a sliver of a first view the chord
        can come out anywhere, and a gate ahead of the robot would stop the ASR from growing."""
        b = self._builders[asr]
        if b.polygon.area < self.params.sliver_area:
            return None
        return b.open_exit(at, accept=lambda e: _outward_x(e) < -0.5 and e.midpoint[0] < 0.3)

    def _reenter(self, t: float, tr: Transition, pose: Pose, pts: ScanPoints) -> list[Event]:
        """Re-enter the known ASR ``tr.dst``: hand the pose over (``tr.rel`` is its frame seen from
        the old one), restore its localisation reference, and take this scan as one of its views."""
        new_pose = compose(inverse(tr.rel), pose)
        self.current = tr.dst
        self.localiser.reset(new_pose)
        kept = self._loc_refs.get(tr.dst)
        if kept is not None:  # the reference it had when the robot left it (its views since: none)
            self.localiser.restore_reference(kept)
        else:
            self.localiser.add_references(self._refs.get(tr.dst, []))
        # The builder joins consecutive viewpoints with a swept corridor; the robot did not walk
        # from the last visit's viewpoint to here, so start the sweep afresh at the new pose.
        self._builders[tr.dst].viewpoints.append(new_pose)
        self._last_view = None
        self._entry, self._armed = (tr.dst, tr.via), False
        events: list[Event] = [ExitCrossed(t, tr.src, tr.exit, tr.dst, tr.via, False)]
        events += self._gm.enter(tr.dst, tr.src, t)
        # this scan already left an ASR: when busy, even the view waits for the next scan
        busy = time.perf_counter() - self._scan_start > _SPARE
        events += self._add_view(t, pts, new_pose, late=busy)
        return events

    def _entrance(self, asr: int, at: tuple[float, float]) -> Exit | None:
        """The exit of ``asr`` the robot came in through at ``at`` (its frame): :func:`entrance`."""
        return entrance(self._asrs[asr].exits, at, self.params.passage_width)

    def _new_asr(self, t: float, origin: Pose, entered_from: int | None, pts: ScanPoints) -> list[Event]:
        """A new ASR whose frame is the robot pose at this scan; the scan is its first view."""
        aid = self._next_id
        self._next_id += 1
        b = AsrBuilder(aid, t, origin, self.params)
        self._builders[aid] = b
        self._asrs[aid] = b.asr
        self.current = aid
        self.localiser.reset()
        self._last_view = None
        # the first view is unioned at once (or, pipelined, first thing next scan): the entrance
        # and the cycle check need it
        self._add_view(t, pts, (0.0, 0.0, 0.0), defer=entered_from is not None)
        events: list[Event] = [AsrCreated(t, aid, origin, entered_from)]
        if entered_from is None:
            # The first ASR (or the first after from_document, checked against the saved map).
            self._gm.add_first(b.asr)
            events += self._gm.check(aid, t)
        return events
