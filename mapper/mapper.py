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

Crossing (§4, simplest form): when the segment from the previous to the current pose crosses an
exit of the current ASR and the current pose lies outside its polygon, a new ASR is created with its
frame at the current pose and global origin = old origin ⊕ pose; its exit nearest the crossing point
is the entrance (``via``). The crossing logic lives in the small ``_crossed_exit``,
``_leave_through``, ``_new_asr`` and ``_entrance`` methods so that re-entry into known ASRs and cycle
checks can extend them.
"""

from __future__ import annotations

import bisect
import math
import time

import numpy as np
import shapely

from mapper.asr_builder import AsrBuilder
from mapper.events import AsrCreated, AsrUpdated, Event, ExitCrossed
from mapper.exits import find_covers
from mapper.lines import ScanPoints, extract_surfaces, scan_points
from mapper.localise import Localiser
from mapper.params import MapperParams
from mapper.se2 import Pose, between, compose, interpolate
from mapper.types import ASR, Exit, Odometry, Scan
from mapper.view import build_view

_ODOM_KEEP = 4096  # odometry readings kept for interpolation (minutes at 20 Hz)


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


class Mapper:
    """ASRs from odometry and laser scans; see the module docstring.

    ``asrs``: id -> :class:`~mapper.types.ASR`; ``current``: id of the ASR the robot is in (None
    before the first scan); ``pose``: robot pose in the current ASR frame; ``global_pose``: in the
    global frame; ``timing``: seconds spent per stage on the last scan (for benchmarks).
    """

    def __init__(self, params: MapperParams | None = None):
        self.params = params or MapperParams()
        self.asrs: dict[int, ASR] = {}
        self.current: int | None = None
        self.localiser = Localiser(self.params)
        self.timing: dict[str, float] = {}
        self._builders: dict[int, AsrBuilder] = {}
        self._odom_t: list[float] = []
        self._odom_pose: list[Pose] = []
        self._last_odom: Pose | None = None
        self._last_view: Pose | None = None
        self._next_id = 1

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
        """Localise, grow the current ASR and detect exit crossings; returns the events."""
        tic = time.perf_counter()
        odo = self.odometry_at(scan.t)
        if odo is None:
            odo = self._last_odom or (0.0, 0.0, 0.0)
        pts = scan_points(scan, self.params)
        timing = self.timing = {"points": time.perf_counter() - tic}
        if self.current is None:
            self._last_odom = odo
            return self._new_asr(scan.t, (0.0, 0.0, 0.0), None, pts)
        delta = between(self._last_odom, odo)
        self._last_odom = odo
        prev = self.pose
        tic = time.perf_counter()
        self.localiser.predict(delta)
        self.localiser.correct(pts.xy)
        pose = self.pose
        timing["localise"] = time.perf_counter() - tic
        crossed = self._crossed_exit(prev, pose) or self._left_elsewhere(prev, pose)
        if crossed is not None:
            return self._leave_through(scan.t, crossed[0], crossed[1], pose, pts)
        if self._is_viewpoint(pose):
            return self._add_view(scan.t, pts, pose)
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

    def _add_view(self, t: float, pts: ScanPoints, pose: Pose) -> list[Event]:
        p = self.params
        timing = self.timing
        tic = time.perf_counter()
        surf = extract_surfaces(pts, p)
        tac = time.perf_counter()
        covers = find_covers(surf, p)
        toc = time.perf_counter()
        view = build_view(surf, p, covers)
        tuc = time.perf_counter()
        builder = self._builders[self.current]
        changed = builder.add_view(view, pose)
        self.localiser.add_reference(pts.xy, pose)
        self._last_view = pose
        timing.update(extract=tac - tic, exits=toc - tac, view=tuc - toc, asr=time.perf_counter() - tuc)
        if not changed:
            return []
        a = builder.asr
        return [AsrUpdated(t, a.id, a.area, a.scans)]

    # --- crossing exits (§4): small methods, meant to be extended --------------------------------
    def _crossed_exit(self, prev: Pose, pose: Pose) -> tuple[Exit, tuple[float, float]] | None:
        """The exit of the current ASR crossed between ``prev`` and ``pose`` (ASR frame) and where,
        if the robot now lies outside the ASR polygon; else None."""
        b = self._builders[self.current]
        if not b.asr.exits or b.polygon.contains(shapely.Point(pose[:2])):
            return None
        for e in b.asr.exits:
            hit, at = _segments_cross(prev, pose, e.a, e.b)
            if hit:
                return e, at
        return None

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
        e = b.open_exit((at.x, at.y))
        return e, (at.x, at.y)

    def _leave_through(
        self, t: float, e: Exit, at: tuple[float, float], pose: Pose, pts: ScanPoints
    ) -> list[Event]:
        """Create the ASR beyond exit ``e`` (crossed at ``at``), its frame at ``pose``."""
        old = self.current
        origin = compose(self.asrs[old].origin, pose)
        events = self._new_asr(t, origin, old, pts)
        new = self.current
        e.to = new
        via = self._entrance(new, between(pose, (at[0], at[1], 0.0))[:2])
        if via is not None:
            via.to = old
        events.append(ExitCrossed(t, old, e.id, new, via.id if via is not None else None, True))
        return events

    def _entrance(self, asr: int, at: tuple[float, float]) -> Exit | None:
        """The exit of ``asr`` nearest the crossing point ``at`` (its frame), within a passage width."""
        best, best_d = None, 2.0 * self.params.passage_width
        for e in self.asrs[asr].exits:
            a, b = np.asarray(e.a), np.asarray(e.b)
            ab = b - a
            tt = float(np.clip(np.dot(np.asarray(at) - a, ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
            d = float(np.hypot(*(a + tt * ab - np.asarray(at))))
            if d < best_d:
                best, best_d = e, d
        return best

    def _new_asr(self, t: float, origin: Pose, entered_from: int | None, pts: ScanPoints) -> list[Event]:
        """A new ASR whose frame is the robot pose at this scan; the scan is its first view."""
        aid = self._next_id
        self._next_id += 1
        b = AsrBuilder(aid, t, origin, self.params)
        self._builders[aid] = b
        self.asrs[aid] = b.asr
        self.current = aid
        self.localiser.reset()
        self._last_view = None
        self._add_view(t, pts, (0.0, 0.0, 0.0))
        return [AsrCreated(t, aid, origin, entered_from)]
