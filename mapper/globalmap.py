"""The global metric map and cycle closing (method.md §4 global poses, §5 the paper's check, §7 extensions).

:class:`GlobalMap` owns the ASR records once they exist, the :class:`~mapper.topology.Topology`, a
spatial index of the ASRs' polygons in the global frame, the cycle decisions, and the ASR pose graph.
The mapper tells it when an ASR is created (:meth:`GlobalMap.add_created`), re-entered
(:meth:`GlobalMap.enter`) or has changed (:meth:`GlobalMap.updated`); it answers with events.

The cycle check (§5), run at creation and whenever the current ASR's area grew by more than
``CycleParams.regrowth_fraction`` since its last check (and, beyond the paper, once more as the
robot leaves it when it grew at all since then: ``CycleParams.leave_check``):

1. c = the current ASR's centre in the global frame.
2. Candidates: ASRs whose global polygon contains c (index query, O(log² N + k)), except the
   current ASR, the ASR it was entered from (and, if ``exclude_hops`` > 1, any ASR that close in the
   topological map) and the current ASR's own duplicates/original.
3. Centre crosscheck: a candidate survives only if its centre lies inside the current polygon.
4. Survivors ranked by IoU; the best is accepted (after surface verification when ``verify``), the
   rest are reported as ``lower-overlap``.
5. Closing: the current ASR becomes a duplicate of the match; the ASR it was entered from is linked,
   through the crossed exit, to the match's exit nearest to that exit in the global frame (§5.5).
6. Every decision is an event (CycleDetected / CycleRejected with its reason) and a ``cycles`` record.
   A rejection repeated at a later growth check with the same reason is not reported twice.

Frames: ``ASR.origin`` is the ASR frame's pose in the global frame (m, m, rad); ``odometry_origin``
keeps the same poses as composed along the creation transitions only, never realigned (the
drifting map the paper accepts), so that evaluation can compare both against ground truth.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Container
from dataclasses import dataclass

import numpy as np
import shapely

from mapper.cycle_params import CycleParams
from mapper.cycles import (
    Alignment,
    SpatialIndex,
    align_points,
    axis_depth,
    centre_of,
    depth_inside,
    exit_pin,
    exit_segments,
    free_space_violation,
    global_centre,
    global_polygon,
    iou,
    surface_points,
)
from mapper.events import CycleDetected, CycleRejected, Event, MapRealigned
from mapper.exits import segment_distance
from mapper.posegraph import Edge, diagonal_info, optimise, relative_covariance
from mapper.se2 import Pose, between, compose, inverse, transform_points
from mapper.topology import Topology, Transition, child_origin
from mapper.types import ASR

#: Reasons of matches whose only crosscheck was the one with their surface alignment applied: found
#: by the search radius (``aligned-crosscheck``), or failing the unaligned one (``realigned-crosscheck``).
_ALIGNED = ("aligned-crosscheck", "realigned-crosscheck")


@dataclass(slots=True)
class CycleRecord:
    """One cycle decision as the map document stores it (``cycles``); ``time`` in s."""

    time: float
    asr: int
    matches: int
    accepted: bool
    iou: float
    reason: str

    def to_dict(self) -> dict:
        return {
            "time": self.time,
            "asr": self.asr,
            "matches": self.matches,
            "accepted": self.accepted,
            "iou": self.iou,
            "reason": self.reason,
        }


def _mutual(poly_a, ca, poly_b, cb, margin: float) -> bool:
    """The centre crosscheck: each centre (m, global) inside the other polygon, at least ``margin``
    (m) from its boundary when ``margin`` > 0."""
    if margin > 0:
        inner_a, inner_b = poly_a.buffer(-margin), poly_b.buffer(-margin)
    else:
        inner_a, inner_b = poly_a, poly_b
    return bool(inner_b.intersects(shapely.Point(ca)) and inner_a.intersects(shapely.Point(cb)))


def _unslid(a: Alignment, pn: np.ndarray) -> Alignment:
    """The alignment without its slide along its open axis (``a.axis``, global frame): where the
    matched surfaces are all parallel (a straight corridor piece), ICP's move along them is not
    measured but drift from wherever it started, so the dead-reckoned placement along the axis is
    kept (and the exits may pin it, :meth:`GlobalMap._pin_by_exits`); the move across the axis and
    the rotation stay. ``pn``: the moved ASR's surface points (global frame, as placed), whose
    centroid's move along the axis is taken back. In the lab world such slides put 13 of 30 closed
    corridor pieces 0.3-1.9 m off along the corridor; without them, 1 of 30."""
    ux, uy = math.cos(a.axis), math.sin(a.axis)
    move = _centroid_move(a.correction, pn)
    k = float(move[0] * ux + move[1] * uy)
    correction = compose((-k * ux, -k * uy, 0.0), a.correction)
    shift = float(np.hypot(*_centroid_move(correction, pn)))
    return dataclasses.replace(a, correction=correction, shift=shift)


def _centroid_move(correction: Pose, pts: np.ndarray) -> np.ndarray:
    """How far (m, global frame) ``correction`` moves the centroid of ``pts`` (global frame)."""
    return transform_points(correction, pts).mean(axis=0) - pts.mean(axis=0)


class GlobalMap:
    """ASRs placed in one global frame, their topology, and cycle closing over them."""

    def __init__(self, params: CycleParams | None = None) -> None:
        self.params = params or CycleParams()
        self.asrs: dict[int, ASR] = {}
        self.topology = Topology()
        self.index = SpatialIndex()
        self.cycles: list[CycleRecord] = []
        self.odometry_origin: dict[int, Pose] = {}
        self.current: int | None = None
        self.checks = 0
        self.realignments = 0
        self._came_from: dict[int, int | None] = {}
        self._checked_area: dict[int, float] = {}
        self._closed: set[int] = set()
        self._partners: dict[int, set[int]] = {}  # ASR -> the ASRs accepted cycles pair it with
        self._rejected: dict[tuple[int, int], float] = {}
        self._reported: set[tuple[int, int, str]] = set()
        self._odometry_edges: list[Edge] = []
        self._loop_edges: list[Edge] = []
        self.alignments: dict[tuple[int, int], Alignment | None] = {}
        """Surface alignment of every verified pair (asr, match), for diagnosis."""

    # -- the mapper's calls -------------------------------------------------------------------
    def add_first(self, asr: ASR) -> None:
        """The first ASR; its ``origin`` (usually the identity) defines the global frame."""
        self.asrs[asr.id] = asr
        self.odometry_origin[asr.id] = tuple(asr.origin)
        self.topology.add_node(asr.id)
        self.current = asr.id
        self._came_from[asr.id] = None
        self.index.upsert(asr.id, global_polygon(asr))

    def add_created(self, asr: ASR, src: int, exit_id: str, via: str | None, crossing_pose: Pose, t: float):
        """ASR ``asr`` was created by crossing exit ``exit_id`` of ``src``; returns the check's events.

        ``crossing_pose``: the robot pose in ``src``'s frame at the scan that created ``asr`` (m, rad);
        it is also ``asr``'s frame seen from ``src``'s. Sets ``asr.origin`` (method.md §4).
        """
        events = self._leave(t)
        parent = self.asrs[src]
        asr.origin = child_origin(parent.origin, crossing_pose)
        self.odometry_origin[asr.id] = child_origin(self.odometry_origin[src], crossing_pose)
        self.asrs[asr.id] = asr
        self.topology.add_creation(src, exit_id, asr.id, via, crossing_pose)
        self._set_exit_to(parent, exit_id, asr.id)
        if via is not None:
            self._set_exit_to(asr, via, src)
        d = math.hypot(crossing_pose[0], crossing_pose[1])
        p = self.params
        info = diagonal_info(max(0.05, p.odometry_sigma_xy * d), max(0.01, p.odometry_sigma_theta * d))
        self._odometry_edges.append(Edge(src, asr.id, tuple(crossing_pose), info))
        self._switch_to(asr.id, src)
        return events + self.check(asr.id, t)

    def enter(self, asr_id: int, src: int | None, t: float) -> list[Event]:
        """The robot re-entered a known ASR from ``src`` (through a known transition)."""
        events = self._leave(t)
        self._switch_to(asr_id, src)
        return events

    def _leave(self, t: float) -> list[Event]:
        """The robot is leaving the current ASR: its last check (``CycleParams.leave_check``) when it
        grew since the one before."""
        n = self.current
        if not self.params.leave_check or n is None or n not in self.asrs:
            return []
        last = self._checked_area.get(n)
        if last is None or self.asrs[n].area <= last:
            return []
        return self.check(n, t)

    def updated(self, asr_id: int, t: float) -> list[Event]:
        """ASR ``asr_id`` changed (grew). Re-checks the current ASR once its area grew materially."""
        asr = self.asrs[asr_id]
        if asr_id != self.current:
            self.index.upsert(asr_id, global_polygon(asr))
            return []
        last = self._checked_area.get(asr_id)
        if last is None or asr.area > last * (1.0 + self.params.regrowth_fraction):
            return self.check(asr_id, t)
        return []

    def closure_depth(self, asr_id: int, polygon: shapely.Geometry | None = None) -> float:
        """How well the accepted cycles of ASR ``asr_id`` still hold: the smallest depth (m, signed,
        positive inside) of either centre inside the other ASR's polygon over every accepted cycle
        pairing ``asr_id`` with another ASR, in the global frame as the ASRs are placed now.
        ``polygon`` (``asr_id``'s frame): a polygon to test in place of its record's (a view about to
        grow it), with the centre that polygon would give. +inf when no accepted cycle names it."""
        partners = self._partners.get(asr_id)
        if not partners:
            return math.inf
        asr = self.asrs[asr_id]
        if polygon is None:
            pa, ca = global_polygon(asr), global_centre(asr)
        else:
            pa = shapely.transform(polygon, lambda xy: transform_points(asr.origin, xy))
            ca = tuple(transform_points(asr.origin, np.array(centre_of(polygon)[0]))[0])
        depth = math.inf
        for k in partners:
            other = self.asrs.get(k)
            if other is None or len(other.boundary) < 3:
                continue
            pb, cb = global_polygon(other), global_centre(other)
            depth = min(depth, depth_inside(pb, ca), depth_inside(pa, cb))
        return depth

    def _pair(self, a: int, b: int) -> None:
        self._partners.setdefault(a, set()).add(b)
        self._partners.setdefault(b, set()).add(a)

    def lookup(self, asr_id: int, exit_id: str):
        """The known transition through ``exit_id`` of ``asr_id`` (re-entry), or None."""
        return self.topology.lookup(asr_id, exit_id)

    def relink(self, asr_id: int, exit_id: str, at: tuple[float, float], radius: float,
               among: Container[int]) -> Transition | None:
        """The known transition out of ``asr_id`` that leads through the place crossed now: exit
        ``exit_id`` has none, but at ``at`` (``asr_id``'s frame, m) lies, within ``radius`` (m), the
        entrance of an ASR a transition out of ``asr_id`` leads into, through an exit that
        ``asr_id`` no longer has; only destinations in ``among`` (those the robot can re-enter).
        Relabelling can drop an exit and give the same doorway a new id
        (its chord moves by more than identity allows, or it vanishes for a view); without this the
        robot crossing that doorway again made a new ASR of known space, every time (simulated
        ``lab``, seed 4: 16 ASRs in 600 s, each entered from one corridor ASR's doorway). The
        transition is moved onto ``exit_id`` and returned; None when no such entrance lies there.

        The entrance is the destination's exit ``via`` placed in ``asr_id``'s frame by the
        transition's ``rel``; where the destination no longer has it, the crossing pose of the
        transition that created the destination (``rel`` itself)."""
        src = self.asrs.get(asr_id)
        if src is None:
            return None
        live = {e.id for e in src.exits}
        best, best_d = None, radius
        for tr in self.topology.out_of(asr_id):
            dst = self.asrs.get(tr.dst)
            if tr.exit in live or dst is None or tr.dst not in among:
                continue
            via = next((e for e in dst.exits if e.id == tr.via), None)
            if via is not None:
                seg = transform_points(tr.rel, np.array([via.a, via.b])).reshape(1, 2, 2)
                d = float(segment_distance(at[0], at[1], seg)[0])
            elif self.topology.entered.get(tr.dst) == tr:
                d = math.hypot(at[0] - tr.rel[0], at[1] - tr.rel[1])
            else:
                continue
            if d < best_d:
                best, best_d = tr, d
        if best is None:
            return None
        moved = self.topology.rekey(asr_id, best.exit, exit_id)
        self._set_exit_to(src, exit_id, moved.dst)
        return moved

    # -- the check ------------------------------------------------------------------------------
    def check(self, n: int, t: float) -> list[Event]:
        """Run the cycle check for ASR ``n`` now (method.md §5); returns the decisions as events."""
        p = self.params
        asr = self.asrs[n]
        if not p.enabled or n in self._closed or asr.area < p.min_area:
            return []
        self.checks += 1
        self._checked_area[n] = asr.area
        poly = global_polygon(asr)
        c = global_centre(asr)
        excluded = self.topology.within(n, p.exclude_hops) | {n}
        if self._came_from.get(n) is not None:
            excluded.add(self._came_from[n])
        own = self.topology.canonical(n)
        events: list[Event] = []
        survivors = []
        centre = shapely.Point(c)
        for m in self.index.containing(*c, radius=p.search_radius):
            if m in excluded or self.topology.canonical(m) == own:
                continue
            pm = self.index.geometry(m)
            cm = global_centre(self.asrs[m])
            overlap = iou(poly, pm)
            if not pm.intersects(centre):
                # Beyond the paper: near, not containing. Only surface alignment can make it a
                # match: the crosscheck is run again with the alignment applied (in _verified).
                align = self._align_near(n, m, poly, cm) if m < n or not p.near_earlier_only else None
                if align is not None:
                    survivors.append((overlap, m, cm, "aligned-crosscheck", align))
                continue
            if not _mutual(poly, c, pm, cm, p.crosscheck_margin):
                # Beyond the paper: drift can fail the crosscheck of a true revisit; aligned by its
                # surfaces, it is held to the near candidates' rules (``align_failed_crosscheck``).
                align = self._align_near(n, m, poly, cm) if p.align_failed_crosscheck else None
                if align is not None:
                    survivors.append((overlap, m, cm, "realigned-crosscheck", align))
                    continue
                self._rejected.setdefault((n, m), t)
                events += self._decide(t, n, m, c, cm, overlap, "centre-crosscheck", False)
            else:
                survivors.append((overlap, m, cm, "centre-crosscheck", None))
        survivors.sort(key=lambda s: (-s[0], s[1]))
        done = False
        for overlap, m, cm, rule, found in survivors:
            if done:
                events += self._decide(t, n, m, c, cm, overlap, "lower-overlap", False)
                continue
            align = found or (self._align(n, m) if (p.verify or p.realign) else None)
            if p.verify and not self._verified(align, n, m, near=rule in _ALIGNED):
                if rule not in _ALIGNED:
                    self._rejected.setdefault((n, m), t)  # hindsight may anchor it later
                events += self._decide(t, n, m, c, cm, overlap, "verification", False)
                continue
            done = True
            events += self._close(t, n, m, c, cm, overlap, rule, align)
        if done and p.realign:
            events += self.realign(t)
        return events

    # -- helpers ------------------------------------------------------------------------------
    def _switch_to(self, asr_id: int, src: int | None) -> None:
        if self.current is not None and self.current in self.asrs:
            self.index.upsert(self.current, global_polygon(self.asrs[self.current]))
        self.current = asr_id
        self._came_from[asr_id] = src
        self.index.upsert(asr_id, global_polygon(self.asrs[asr_id]))

    @staticmethod
    def _set_exit_to(asr: ASR, exit_id: str | None, to: int, overwrite: bool = True) -> None:
        for e in asr.exits:
            if e.id == exit_id and (overwrite or e.to is None):
                e.to = to

    def _decide(self, t, n, m, c, cm, overlap, reason, accepted) -> list[Event]:
        key = (n, m, reason)
        if not accepted and key in self._reported:
            return []
        self._reported.add(key)
        self.cycles.append(CycleRecord(float(t), n, m, accepted, float(overlap), reason))
        cls = CycleDetected if accepted else CycleRejected
        return [cls(float(t), n, m, tuple(c), tuple(cm), float(overlap), reason)]

    def _align_near(self, n: int, m: int, poly_n: shapely.Geometry, cm: tuple[float, float]
                    ) -> Alignment | None:
        """The surface alignment of n onto the nearby m when it verifies, constrains both axes
        (``verify_min_constraint``) and explains ``verify_near_min_inliers`` of the surfaces (its
        alignment is the only evidence), else None. Not tried when m's centre lies farther from n's
        polygon (global frame) than the largest correction allowed: no verified alignment could
        bring it inside."""
        p = self.params
        if not p.verify or poly_n.distance(shapely.Point(cm)) > p.verify_max_correction:
            return None
        align = self._align(n, m, gate=max(1.0, p.search_radius))
        if (
            self._verified(align, n, m, near=True)
            and align.constraint >= p.verify_min_constraint
            and align.inliers >= p.verify_near_min_inliers
            and self._within_drift(align, n, m)
            and self._parent_agrees(align, n, m)
        ):
            return align
        return None

    def _parent_agrees(self, a: Alignment, n: int, m: int) -> bool:
        """``verify_parent``: the ASR n was entered from, moved by ``a.correction`` (global frame),
        and m keep each other's surfaces out of their free space (``verify_max_violation``).
        True when off, or when n was entered from no ASR (or from m)."""
        p = self.params
        src = self._came_from.get(n)
        if not p.verify_parent or src is None or src == m or src not in self.asrs:
            return True
        if len(self.asrs[src].boundary) < 3:
            return True
        ps, _ = surface_points(self.asrs[src], p.sample_spacing)
        pm, _ = surface_points(self.asrs[m], p.sample_spacing)
        return self._moved_violation(src, ps, a.correction, m, pm) <= p.verify_max_violation

    def _within_drift(self, a: Alignment, n: int, m: int) -> bool:
        """``near_drift_sigmas``: the alignment moves n's centre (global frame) no farther than that
        many of the pose graph's standard deviations of n relative to m, along the move
        (:meth:`_axis_sigma`): a match the drift between them cannot explain is another place.
        True when off, or when no chain of edges joins them."""
        k = self.params.near_drift_sigmas
        if k <= 0:
            return True
        asr = self.asrs[n]
        c0, c1 = global_centre(asr), global_centre(asr, compose(a.correction, asr.origin))
        move = math.hypot(c1[0] - c0[0], c1[1] - c0[1])
        if move < 1e-9:
            return True
        sigma = self._axis_sigma(n, m, math.atan2(c1[1] - c0[1], c1[0] - c0[0]))
        return sigma is None or move <= k * sigma

    def _align(self, n: int, m: int, gate: float = 1.0) -> Alignment | None:
        """Surface alignment of n onto m (see :meth:`_align_pair`); ``gate``: ICP's first
        correspondence distance (m), about the largest drift it is meant to pull in."""
        a = self._align_pair(n, m, gate)
        self.alignments[(n, m)] = a
        return a

    def _align_pair(self, n: int, m: int, gate: float) -> Alignment | None:
        p = self.params
        pn, nn = surface_points(self.asrs[n], p.sample_spacing)
        pm, nm = surface_points(self.asrs[m], p.sample_spacing)
        # Align the smaller set onto the larger one: the inlier fraction is then about the part
        # of the smaller ASR the larger one explains.
        if len(pn) <= len(pm):
            a = align_points(pn, pm, nm, p.verify_inlier_distance, gate, p_normals=nn)
        else:
            a = align_points(pm, pn, nn, p.verify_inlier_distance, gate, p_normals=nm)
            a = None if a is None else dataclasses.replace(a, correction=inverse(a.correction))
        if a is None:
            return None
        if a.constraint < p.verify_constrained:
            a = self._pin_by_exits(_unslid(a, pn), n, m, pn)
        # Free-space consistency: once aligned, neither ASR may show walls inside the other's space.
        return dataclasses.replace(a, violation=self._moved_violation(n, pn, a.correction, m, pm))

    def _moved_violation(self, k: int, pk: np.ndarray, correction: Pose, m: int, pm: np.ndarray) -> float:
        """The larger fraction of surface points inside the other's free space
        (``verify_free_space_margin`` deep), ASR k moved by ``correction`` against ASR m as placed;
        ``pk``, ``pm``: their surface points (global frame, as placed)."""
        margin = self.params.verify_free_space_margin
        poly_k = shapely.transform(global_polygon(self.asrs[k]), lambda c: transform_points(correction, c))
        return max(
            free_space_violation(transform_points(correction, pk), global_polygon(self.asrs[m]), margin),
            free_space_violation(pm, poly_k, margin),
        )

    def _pin_by_exits(self, a: Alignment, n: int, m: int, pn: np.ndarray) -> Alignment:
        """``exit_pin_sigmas``: an alignment whose surfaces left its axis open (a straight corridor
        piece), moved along it so that the exits of n (aligned) meet those of m (:func:`exit_pin`,
        within ``verify_inlier_distance``); the drift bound of :meth:`_axis_sigma` is how far they
        may have been apart. ``pn``: n's surface points (global frame), for the new ``shift``. The
        alignment unchanged when the exits do not say where along the axis n lies."""
        p = self.params
        k = p.exit_pin_sigmas
        sigma = self._axis_sigma(n, m, a.axis) if k > 0 else None
        if sigma is None:
            return a
        placed = compose(a.correction, self.asrs[n].origin)
        pin = exit_pin(exit_segments(self.asrs[n], placed), exit_segments(self.asrs[m]), a.axis,
                       p.verify_inlier_distance, min(k * sigma, p.verify_max_correction))
        if pin is None:
            return a
        s = pin[0]
        correction = compose((s * math.cos(a.axis), s * math.sin(a.axis), 0.0), a.correction)
        shift = float(np.hypot(*_centroid_move(correction, pn)))
        return dataclasses.replace(a, correction=correction, shift=shift, pinned=s)

    def _axis_sigma(self, n: int, m: int, axis: float) -> float | None:
        """Standard deviation (m) of where n lies relative to m along the direction ``axis`` (rad,
        global frame), by the pose graph (odometry and loop edges): the drift the chain of
        transitions and the loops closed between them allow (:func:`relative_covariance`). None
        when no chain joins them."""
        cov = relative_covariance({q: tuple(r.origin) for q, r in self.asrs.items()},
                                  self._odometry_edges + self._loop_edges, m, n)
        if cov is None:
            return None
        d = np.array([math.cos(axis), math.sin(axis)])
        return math.sqrt(max(float(d @ cov[:2, :2] @ d), 0.0))

    def _verified(self, a: Alignment | None, n: int, m: int, near: bool = False,
                  margin: float | None = None) -> bool:
        """The alignment is good, and with it applied to n the centre crosscheck still passes: by
        ``verify_crosscheck_margin`` after an unaligned crosscheck passed, by ``crosscheck_margin``
        for a ``near`` candidate (its aligned crosscheck is the only one), by ``margin`` (m) when
        given (hindsight: ``hindsight_margin``). The free-space violation allowed is
        ``verify_crosschecked_violation`` after an unaligned crosscheck passed in full with half the
        surfaces agreeing (``verify_near_min_inliers``) and fixing the alignment in every direction
        (``verify_constrained``), else ``verify_max_violation``."""
        p = self.params
        if a is None:
            return False
        crosschecked = margin is None and not near  # the unaligned crosscheck passed in full
        if margin is None:
            margin = p.crosscheck_margin if near else min(p.crosscheck_margin, p.verify_crosscheck_margin)
        violation = p.verify_max_violation
        if crosschecked and a.inliers >= p.verify_near_min_inliers and a.constraint >= p.verify_constrained:
            violation = max(violation, p.verify_crosschecked_violation)
        moved = compose(a.correction, self.asrs[n].origin)
        poly_n, c_n = global_polygon(self.asrs[n], moved), global_centre(self.asrs[n], moved)
        poly_m, c_m = global_polygon(self.asrs[m]), global_centre(self.asrs[m])
        return (
            _mutual(poly_n, c_n, poly_m, c_m, margin)
            and a.rms <= p.verify_max_residual
            and a.inliers >= p.verify_min_inliers
            and a.shift <= p.verify_max_correction
            and abs(a.correction[2]) <= p.verify_max_rotation
            and a.violation <= violation
            and (a.constraint >= p.verify_constrained
                 or (a.across >= p.verify_min_across
                     and self._placed_along_axis(a, n, m, near, (poly_n, c_n), (poly_m, c_m))))
        )

    def _placed_along_axis(self, a: Alignment, n: int, m: int, near: bool, placed_n: tuple,
                           placed_m: tuple) -> bool:
        """Whether something other than the surfaces says where along its open axis an alignment
        of a straight piece puts n: the exits pinned it, or (not for a ``near`` candidate) the
        topology anchors it or the pose graph bounds the drift along it. ``placed_n``,
        ``placed_m``: as :meth:`_drift_bounded` takes them."""
        return a.pinned is not None or (
            not near and (self._anchored(n, m) or self._drift_bounded(a, n, m, placed_n, placed_m)))

    def _drift_bounded(self, a: Alignment, n: int, m: int, placed_n: tuple, placed_m: tuple) -> bool:
        """Whether the open axis of an alignment (``a.axis``, global frame: along a straight
        corridor) is bounded by what the pose graph says of the drift between n and m
        (``drift_bound_sigmas``): each centre can move that many standard deviations along the axis
        and stay inside the other ASR. ``placed_n``, ``placed_m``: (polygon, centre) of each in the
        global frame, n's with the alignment applied."""
        k = self.params.drift_bound_sigmas
        sigma = self._axis_sigma(n, m, a.axis) if k > 0 else None
        if sigma is None:
            return False
        (poly_n, c_n), (poly_m, c_m) = placed_n, placed_m
        return min(axis_depth(poly_m, c_n, a.axis), axis_depth(poly_n, c_m, a.axis)) >= k * sigma

    def _anchored(self, n: int, m: int) -> bool:
        """Whether the topology already places n beside m (``topological_anchor``): a neighbour of n
        is, by an accepted cycle, the same place as a neighbour of m (two different ASRs, one the
        duplicate of the other). A straight corridor piece's surfaces cannot say where along it n
        lies; the closure next to it can: n and m lie beside one place."""
        if not self.params.topological_anchor:
            return False
        top = self.topology  # the ASR n was entered from is one of its neighbours
        mine, theirs = top.within(n, 1) - {n, m}, top.within(m, 1) - {m, n}
        return any(q != a and top.canonical(q) == top.canonical(a) for a in mine for q in theirs)

    def _close(self, t, n, m, c, cm, overlap, reason, align: Alignment | None) -> list[Event]:
        p = self.params
        dup, match = self.asrs[n], self.asrs[m]
        dup.duplicate_of = m
        self._closed.add(n)
        good = align is not None and self._verified(align, n, m, near=reason in _ALIGNED)
        # dup's frame corrected onto match (global frame), then match's frame seen from dup's.
        dup_origin = compose(align.correction, dup.origin) if good else dup.origin
        rel_nm = between(dup_origin, match.origin)
        entry = self.topology.entered.get(n)
        if entry is None:
            self.topology.close_onto(n, m, None, rel_nm)
        else:
            parent = self.asrs[entry.src]
            crossed = next((e for e in parent.exits if e.id == entry.exit), None)
            g = self._nearest_exit(parent, crossed, match)
            self.topology.close_onto(n, m, g.id if g else None, compose(entry.rel, rel_nm))
            self._set_exit_to(parent, entry.exit, m)
            if g is not None:
                self._set_exit_to(match, g.id, entry.src, overwrite=False)
        if good:
            info = self._loop_info(align, dup_origin[2])
        else:
            info = diagonal_info(p.loop_sigma_unverified_xy, p.loop_sigma_unverified_theta)
        self._loop_edges.append(Edge(m, n, inverse(rel_nm), info))
        events = self._decide(t, n, m, c, cm, overlap, reason, True)
        self._pair(n, m)
        if p.hindsight and reason != "hindsight":
            events += self._hindsight(t, n, m, align.correction if good else (0.0, 0.0, 0.0))
        return events

    def _loop_info(self, align: Alignment, heading: float) -> np.ndarray:
        """Information matrix (1/m², 1/rad²) of a verified loop edge, from what its alignment observed.

        The edge's translation error is expressed in the duplicate's frame, whose global heading is
        ``heading`` (rad). A surface constrains translation only along its normal: the alignment's
        normal scatter has eigenvalue ``constraint`` along ``axis`` (global frame) and
        1 - ``constraint`` across it. An axis with an eigenvalue of at least
        ``loop_constraint_full`` gets ``loop_sigma_xy``; below that the information falls in
        proportion, down to that of an unverified edge (``loop_sigma_unverified_xy``): along a
        straight corridor the alignment says nothing about where along it the two ASRs lie, and
        the edge must not claim ``loop_sigma_xy`` there (in the lab world such edges were 0.7-6 m
        off along the corridor, and pulled the relaxed map and the re-entry hand-overs with them).
        Rotation is observed by any wall: ``loop_sigma_theta``.
        """
        p = self.params
        full, loose = 1.0 / p.loop_sigma_xy**2, 1.0 / p.loop_sigma_unverified_xy**2

        def weight(eig: float) -> float:
            return max(loose, full * min(1.0, max(eig, 0.0) / p.loop_constraint_full))

        phi = align.axis - heading
        c, s = math.cos(phi), math.sin(phi)
        rot = np.array([[c, -s], [s, c]])
        info = np.zeros((3, 3))
        info[:2, :2] = rot @ np.diag([weight(align.constraint), weight(1.0 - align.constraint)]) @ rot.T
        info[2, 2] = 1.0 / p.loop_sigma_theta**2
        return info

    def _nearest_exit(self, parent: ASR, crossed, match: ASR):
        """The match's exit whose global midpoint is nearest the crossed exit's (None: no exits)."""
        if not match.exits:
            return None
        if crossed is None:
            ref = np.array(global_centre(match))
        else:
            ref = transform_points(parent.origin, np.array(crossed.midpoint))[0]
        mids = transform_points(match.origin, np.array([e.midpoint for e in match.exits]))
        return match.exits[int(np.argmin(np.hypot(*(mids - ref).T)))]

    def _hindsight(self, t: float, n: int, m: int, correction: Pose) -> list[Event]:
        """§7: re-examine earlier rejections (a, b) with a near n and b near m topologically: those of
        the crosscheck (the paper's case) and, beyond it, those of verification (with n -> m accepted
        a straight piece beside them is now anchored, ``topological_anchor``).

        The accepted match n -> m says how far the map had drifted there: ``correction`` (global
        frame) moves n onto m (identity without a surface alignment). Applied to a, with both ASRs
        as they are now (grown since the rejection), the centre crosscheck is run again (with
        ``hindsight_margin`` when ``verify``); a pair that passes (and verifies, when ``verify``)
        is accepted with reason ``hindsight``.
        """
        p = self.params
        margin = min(p.hindsight_margin, p.crosscheck_margin) if p.verify else p.crosscheck_margin
        near_n, near_m = self.topology.within(n, p.hindsight_hops), self.topology.within(m, p.hindsight_hops)
        events: list[Event] = []
        for a, b in sorted(self._rejected):
            if a in self._closed or a not in near_n or b not in near_m:
                continue
            if self.topology.canonical(a) == self.topology.canonical(b):
                continue
            moved = compose(correction, self.asrs[a].origin)
            pa, ca = global_polygon(self.asrs[a], moved), global_centre(self.asrs[a], moved)
            pb, cb = global_polygon(self.asrs[b]), global_centre(self.asrs[b])
            if not _mutual(pa, ca, pb, cb, margin):
                continue
            del self._rejected[(a, b)]
            align = self._align(a, b) if (p.verify or p.realign) else None
            if p.verify and not self._verified(align, a, b, margin=margin):
                continue
            events += self._close(t, a, b, ca, cb, iou(pa, pb), "hindsight", align)
        return events

    # -- realignment ------------------------------------------------------------------------------
    def realign(self, t: float) -> list[Event]:
        """Relax the ASR pose graph (odometry + loop edges) and move every ASR's origin (§7)."""
        if not self._loop_edges:
            return []
        poses = {k: tuple(a.origin) for k, a in self.asrs.items()}
        res = optimise(
            poses,
            self._odometry_edges + self._loop_edges,
            fixed=min(poses),
            iterations=self.params.posegraph_iterations,
        )
        moved = 0.0
        for k, a in self.asrs.items():
            q = res.poses[k]
            moved = max(moved, math.hypot(q[0] - a.origin[0], q[1] - a.origin[1]))
            a.origin = q
        self.index.rebuild({k: global_polygon(a) for k, a in self.asrs.items()})
        self.realignments += 1
        return [MapRealigned(float(t), len(self.asrs), len(self._loop_edges), moved, res.chi2_after)]

    # -- the document ---------------------------------------------------------------------------
    def sync_exits(self) -> None:
        """Set every exit's ``to`` from the topology (exits may have been recomputed since)."""
        for k, a in self.asrs.items():
            dest = self.topology.destinations(k)
            for e in a.exits:
                e.to = dest.get(e.id, e.to)

    def restore(self, asrs: list[ASR], links, cycles: list[CycleRecord]) -> None:
        """Rebuild from a loaded document (ASRs in creation order, links, cycle records).

        Transitions' relative poses are taken from the saved origins (the document does not keep
        them); odometry edges from creation links, loop edges from accepted cycles.
        """
        p = self.params
        for a in asrs:
            self.asrs[a.id] = a
            self.odometry_origin[a.id] = tuple(a.origin)
            self.topology.add_node(a.id)
            if a.duplicate_of is not None:
                self.topology.duplicate_of[a.id] = a.duplicate_of
                self._closed.add(a.id)
        first = asrs[0].id if asrs else None
        for ln in links:
            o_src, o_dst = self.asrs[ln.src].origin, self.asrs[ln.dst].origin
            self.topology.add_link(ln.src, ln.exit, ln.dst, ln.via, between(o_src, o_dst), ln.oneway)
            # A creation is the first two-way link into a later ASR, or the one-way link a
            # duplicate keeps back to the ASR it was entered from.
            if ln.oneway:
                child, parent, via, crossed = ln.src, ln.dst, ln.exit, ln.via
            elif (
                ln.dst not in self.topology.entered
                and ln.dst != first
                and (self.asrs[ln.dst].created >= self.asrs[ln.src].created)
            ):
                child, parent, via, crossed = ln.dst, ln.src, ln.via, ln.exit
            else:
                continue
            rel = between(self.asrs[parent].origin, self.asrs[child].origin)
            self.topology.entered[child] = Transition(parent, crossed, child, via, rel)
            self._came_from[child] = parent
            d = math.hypot(rel[0], rel[1])
            info = diagonal_info(max(0.05, p.odometry_sigma_xy * d), max(0.01, p.odometry_sigma_theta * d))
            self._odometry_edges.append(Edge(parent, child, rel, info))
        self.cycles = list(cycles)
        for r in self.cycles:
            self._reported.add((r.asr, r.matches, r.reason))
            if r.accepted and r.asr in self.asrs and r.matches in self.asrs:
                self._pair(r.asr, r.matches)
                rel = between(self.asrs[r.matches].origin, self.asrs[r.asr].origin)
                self._loop_edges.append(
                    Edge(r.matches, r.asr, rel, diagonal_info(p.loop_sigma_xy, p.loop_sigma_theta))
                )
        geoms = {k: global_polygon(a) for k, a in self.asrs.items()}
        self.index.rebuild(geoms)
        if asrs:
            self.current = asrs[-1].id
