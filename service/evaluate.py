"""Evaluation of a map against ground truth (shared/design/interfaces.md, "Evaluation against ground truth").

Ground truth is a :class:`Track` of true robot poses (the corrected poses of a corrected CARMEN log of
the same run). Between its samples the truth is carried by the replayed odometry's increments:
``truth(t) = truth(t_k) ⊕ (odo(t_k)⁻¹ ⊕ odo(t))`` with t_k the last truth sample at or before t, so
a sparse truth (a corrected scan every few seconds) still gives the pose at any scan.

- An ASR's **true frame** is the true pose at its ``created`` time.
- Two ASRs **truly overlap** when, in their true frames, each one's centre lies inside the other's
  polygon.
- A reported (accepted) cycle is a **true positive** when its two ASRs truly overlap.
- A **revisit** is an ASR that truly overlaps an earlier ASR other than the one it was entered from;
  it is **detected** when an accepted cycle links it, or one of the next two ASRs created, to that
  earlier ASR or to a duplicate of it (or to the original it duplicates).
- Each **transition's error**: for every ASR entered from another (its parent), the dead-reckoned
  pose of its frame in the parent's (the crossing pose the mapper's odometry edge holds) against the
  true one: the distance between the two frames (m), the position error (m) and the heading error
  (rad). The drift gates of cycle checking model these (``CycleParams.odometry_sigma_xy`` and
  ``odometry_sigma_theta``, per metre between the frames).
- The ASR frames' error: RMS distance between the ASRs' global origins and their true positions
  after the best rigid 2D alignment of the two (the global frame is arbitrary), and the RMS of the
  relative heading error; for the realigned map and for the dead-reckoned one.

ASRs created more than ``margin`` seconds (default 60 s) outside the truth's time span are left out
of every figure (and counted): odometry carries the truth well over seconds, not over minutes.

Corrected logs replayed on their own (``*-corrected.log.gz``): :func:`rebuild_corrected` turns their
embedded ``ODOM`` increments back into drifting odometry (shared/data/SOURCES.md, "Raw odometry
inside the corrected logs") and returns the FLASER poses as the truth.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

from mapper.se2 import Pose, between, compose, interpolate, transform_points, wrap_array
from mapper.types import Odometry, Scan
from service.carmen import CarmenReader, LaserRecord, OdomRecord


class Track:
    """Poses (m, m, rad) by time (s), interpolated linearly (shortest turn) and held at the ends."""

    def __init__(self, times: Iterable[float] = (), poses: Iterable[Pose] = ()):
        pairs = sorted(zip(times, poses, strict=True), key=lambda p: p[0])
        self.t = [float(t) for t, _ in pairs]
        self.poses = [tuple(float(v) for v in p) for _, p in pairs]

    def __len__(self) -> int:
        return len(self.t)

    def append(self, t: float, pose: Pose) -> None:
        if self.t and t < self.t[-1]:
            i = bisect.bisect_right(self.t, t)
            self.t.insert(i, t)
            self.poses.insert(i, pose)
        else:
            self.t.append(t)
            self.poses.append(pose)

    def span(self) -> tuple[float, float]:
        return (self.t[0], self.t[-1]) if self.t else (math.inf, -math.inf)

    def at(self, t: float) -> Pose:
        i = bisect.bisect_left(self.t, t)
        if i <= 0:
            return self.poses[0]
        if i >= len(self.t):
            return self.poses[-1]
        t0, t1 = self.t[i - 1], self.t[i]
        return interpolate(self.poses[i - 1], self.poses[i], 0.0 if t1 <= t0 else (t - t0) / (t1 - t0))


def true_pose(truth: Track, odometry: Track, t: float) -> Pose:
    """The true robot pose at time t: the last truth sample before t carried on by odometry."""
    i = max(0, bisect.bisect_right(truth.t, t) - 1)
    tk = truth.t[i]
    return compose(truth.poses[i], between(odometry.at(tk), odometry.at(t)))


def truth_from_log(path: str | Path) -> Track:
    """The logged robot poses of every laser line (FLASER ``x y theta``, ROBOTLASER1 ``robot_*``)."""
    tr = Track()
    for rec in CarmenReader(path):
        if isinstance(rec, LaserRecord):
            tr.append(rec.t, rec.pose)
    return tr


def read_truth(truth: str | Path | Track) -> Track:
    """The truth a replay is scored against: a :class:`Track` as given, else the logged poses of the
    log named (:func:`truth_from_log`, world frame of that log). A log without a pose is a
    ``ValueError`` naming it: read before a replay runs, which would otherwise score nothing."""
    if isinstance(truth, Track):
        return truth
    track = truth_from_log(truth)
    if not len(track):
        raise ValueError(f"{truth}: no robot pose could be read to use as the truth (FLASER or "
                         "ROBOTLASER1 lines); the warnings above name the lines that were skipped")
    return track


def is_corrected(path: str | Path, probe: int = 50) -> bool:
    """Whether a log is a corrected one with embedded raw increments: its laser lines are followed by
    a reset ``ODOM`` at the same pose with timestamp 0 (SOURCES.md)."""
    last: LaserRecord | None = None
    seen = 0
    for rec in CarmenReader(path, quiet=True):
        if isinstance(rec, LaserRecord):
            last = rec
            seen += 1
            if seen > probe:
                return False
        elif isinstance(rec, OdomRecord) and last is not None and rec.t == 0.0:
            return bool(np.allclose(rec.pose, last.pose, atol=1e-4))
    return False


def rebuild_corrected(path: str | Path, retime_period: float = 1.0) -> tuple[list[Odometry | Scan], Track]:
    """Drifting odometry rebuilt from a corrected log's ODOM increments, its scans, and its truth.

    Each laser line k carries the corrected pose C_k; the last ``ODOM`` before line k+1 is
    C_k ⊕ (raw increment), so the raw increment is C_k⁻¹ ⊕ O and the dead-reckoned pose
    D_{k+1} = D_k ⊕ (C_k⁻¹ ⊕ O). D starts at C_0. Returns ([Odometry(t_k, D_k), Scan_k, ...], truth).

    A log whose timestamps lost their precision (``csail-corrected.log.gz`` writes ``1.13486e+09``:
    many scans share one time) is re-timed ``retime_period`` seconds apart from its first scan, for
    the inputs and the truth alike (the mapper needs distinct times to interpolate odometry).
    """
    inputs: list[Odometry | Scan] = []
    truth = Track()
    corrected: Pose | None = None
    dead: Pose | None = None
    odom: Pose | None = None
    for rec in CarmenReader(path):
        if isinstance(rec, OdomRecord):
            if rec.t != 0.0:  # timestamp 0: the reset line that follows each corrected scan
                odom = rec.pose
            continue
        if not isinstance(rec, LaserRecord):
            continue
        if corrected is None:
            dead = rec.pose
        else:
            dead = compose(dead, between(corrected, odom if odom is not None else corrected))
        corrected, odom = rec.pose, None
        truth.append(rec.t, rec.pose)
        inputs.append(Odometry(rec.t, *dead))
        inputs.append(rec.scan())
    if len(set(truth.t)) < len(truth.t):
        t0 = truth.t[0]
        poses = truth.poses
        truth = Track([t0 + k * retime_period for k in range(len(poses))], poses)
        inputs = [
            Odometry(truth.t[k // 2], r.x, r.y, r.theta)
            if isinstance(r, Odometry)
            else dataclasses.replace(r, t=truth.t[k // 2])
            for k, r in enumerate(inputs)
        ]
    return inputs, truth


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Figures of one map against truth (see the module docstring); errors in m and rad."""

    asrs: int
    evaluated: int
    cycles: int
    true_positives: int
    false_positives: int
    revisits: int
    detected: int
    frame_error_before: float
    frame_error_after: float
    heading_error_before: float
    heading_error_after: float
    revisit_drift: tuple[float, ...] = ()
    """m, one per revisit: how far the dead-reckoned ASR frames place the revisiting ASR from the
    earlier one, against the truth (the smallest over the earlier ASRs it overlaps). The cycle check
    compares ASRs placed this far off: beyond an ASR's size, no centre crosscheck can pass."""
    true_pairs: tuple[tuple[int, int, float], ...] = ()
    """(ASR, the earlier ASR it matched, the decision's time in s) of each true positive."""
    false_depths: tuple[tuple[int, int, float, float], ...] = ()
    """(ASR, the ASR it matched, how far the first's true centre lies inside the second's true
    polygon, and the second's inside the first's; m, negative outside) of each false positive: a
    few centimetres outside is a shallow closure of the same place, metres outside a closure of
    another place (:func:`describe_false`)."""
    transition_errors: tuple[tuple[float, float, float], ...] = ()
    """(distance between the two frames in m, position error in m, heading error in rad, signed)
    of each transition, parent to child, by the dead-reckoned frames against the true ones (see the
    module docstring): what the odometry edges of the pose graph got wrong."""

    @property
    def false_pairs(self) -> tuple[tuple[int, int], ...]:
        """(ASR, the ASR it matched) of each false positive."""
        return tuple((i, j) for i, j, _, _ in self.false_depths)

    @property
    def precision(self) -> float:
        return self.true_positives / self.cycles if self.cycles else math.nan

    @property
    def recall(self) -> float:
        return self.detected / self.revisits if self.revisits else math.nan


def _rigid_error(est: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """RMS position error (m) after the best rigid 2D fit of est onto true, and RMS heading error (rad)."""
    if len(est) < 2:
        return 0.0, 0.0
    pe, pt = est[:, :2], true[:, :2]
    me, mt = pe.mean(axis=0), pt.mean(axis=0)
    h = (pe - me).T @ (pt - mt)
    th = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(th), math.sin(th)
    fitted = (pe - me) @ np.array([[c, s], [-s, c]]) + mt
    pos = float(np.sqrt(np.mean(np.sum((fitted - pt) ** 2, axis=1))))
    dth = wrap_array(est[:, 2] + th - true[:, 2])
    dth = wrap_array(dth - math.atan2(np.mean(np.sin(dth)), np.mean(np.cos(dth))))
    return pos, float(np.sqrt(np.mean(dth**2)))


def true_outlines(asrs: list[dict], truth: Track, odometry: Track
                  ) -> tuple[dict[int, Pose], dict[int, shapely.Polygon], dict[int, shapely.Point]]:
    """Each ASR of a map document's ``asrs`` placed by the truth: its true frame (the true pose at its
    ``created`` time), its boundary polygon and its centre point, all in the truth's frame (m, rad)."""
    frames = {a["id"]: true_pose(truth, odometry, a["created"]) for a in asrs}
    polys = {
        a["id"]: shapely.Polygon(transform_points(frames[a["id"]], np.array(a["boundary"], dtype=float)))
        for a in asrs
    }
    for k, g in polys.items():
        if not g.is_valid:
            polys[k] = g.buffer(0)
    centres = {
        a["id"]: shapely.Point(transform_points(frames[a["id"]], np.array(a["centre"], dtype=float))[0])
        for a in asrs
    }
    return frames, polys, centres


def places(doc: dict) -> Callable[[int], set[int]]:
    """``same_place(j)``: ASR ``j`` of the map document with the ASRs it duplicates and those that
    duplicate it (the map's own record of one space seen twice)."""
    dup_of = {a["id"]: a["duplicate_of"] for a in doc["asrs"] if a.get("duplicate_of") is not None}

    def same_place(j: int) -> set[int]:
        out = {j} | {k for k, m in dup_of.items() if m == j}
        while j in dup_of:
            j = dup_of[j]
            out.add(j)
        return out

    return same_place


def evaluate(
    doc: dict,
    truth: Track,
    odometry: Track,
    entered_from: dict[int, int | None],
    origins_before: dict[int, Pose] | None = None,
    margin: float = 60.0,
) -> Evaluation:
    """Score a map document (``asrmap/map/1``) against ``truth``.

    ``odometry``: the odometry the mapper was given (odometry frame), to carry truth between its
    samples; ``entered_from``: ASR id -> the ASR it was entered from; ``origins_before``: the
    dead-reckoned origins to compare with the document's (realigned) ones, and whose transitions'
    errors are measured (the document's origins when not given).
    """
    t0, t1 = truth.span()
    asrs = [a for a in doc["asrs"] if t0 - margin <= a["created"] <= t1 + margin]
    ids = [a["id"] for a in asrs]
    order = {k: n for n, k in enumerate(ids)}
    frames, polys, centres = true_outlines(asrs, truth, odometry)

    def overlap(i: int, j: int) -> bool:
        return polys[j].covers(centres[i]) and polys[i].covers(centres[j])

    def depth(i: int, j: int) -> float:  # m: i's true centre inside j's true polygon (< 0: outside)
        d = float(polys[j].boundary.distance(centres[i]))
        return d if polys[j].covers(centres[i]) else -d

    same_place = places(doc)

    accepted = [
        c for c in doc.get("cycles", []) if c["accepted"] and c["asr"] in order and c["matches"] in order
    ]
    tp = [c for c in accepted if overlap(c["asr"], c["matches"])]
    fp = tuple((c["asr"], c["matches"]) for c in accepted if not overlap(c["asr"], c["matches"]))
    links: dict[int, set[int]] = {}
    for c in accepted:
        links.setdefault(c["asr"], set()).add(c["matches"])
        links.setdefault(c["matches"], set()).add(c["asr"])
    revisits = detected = 0
    drift: list[float] = []
    before_of = origins_before or {a["id"]: tuple(a["origin"]) for a in asrs}
    tree = shapely.STRtree([polys[k] for k in ids])
    for n, i in enumerate(ids):
        earlier = {
            ids[int(j)]
            for j in tree.query(centres[i], predicate="intersects")
            if order[ids[int(j)]] < n and ids[int(j)] != entered_from.get(i) and overlap(i, ids[int(j)])
        }
        if not earlier:
            continue
        revisits += 1
        drift.append(min(_placement_error(before_of, frames, j, i) for j in earlier))
        targets = set().union(*(same_place(j) for j in earlier))
        if any(links.get(k, set()) & targets for k in ids[n : n + 3]):
            detected += 1
    transitions = []
    for i in ids:
        j = entered_from.get(i)
        if j in order:
            e, t = between(tuple(before_of[j]), tuple(before_of[i])), between(frames[j], frames[i])
            transitions.append((math.hypot(e[0], e[1]), math.hypot(e[0] - t[0], e[1] - t[1]),
                                math.remainder(e[2] - t[2], math.tau)))
    est_after = np.array([doc["asrs"][[a["id"] for a in doc["asrs"]].index(k)]["origin"] for k in ids])
    true = np.array([frames[k] for k in ids])
    before = np.array([origins_before[k] for k in ids]) if origins_before else est_after
    eb, hb = _rigid_error(before, true) if len(ids) else (0.0, 0.0)
    ea, ha = _rigid_error(est_after, true) if len(ids) else (0.0, 0.0)
    return Evaluation(
        asrs=len(doc["asrs"]),
        evaluated=len(ids),
        cycles=len(accepted),
        true_positives=len(tp),
        false_positives=len(fp),
        revisits=revisits,
        detected=detected,
        frame_error_before=eb,
        frame_error_after=ea,
        heading_error_before=hb,
        heading_error_after=ha,
        revisit_drift=tuple(drift),
        true_pairs=tuple((c["asr"], c["matches"], float(c["time"])) for c in tp),
        false_depths=tuple((i, j, depth(i, j), depth(j, i)) for i, j in fp),
        transition_errors=tuple(transitions),
    )


def describe_false(depths: Iterable[tuple[int, int, float, float]]) -> str:
    """The false closures of :attr:`Evaluation.false_depths` in words, e.g. ``48 -> 24 (centres
    -0.05 / 0.31 m inside)``: each centre's true depth inside the other ASR (m, negative outside)."""
    return ", ".join(f"{i} -> {j} (centres {a:.2f} / {b:.2f} m inside)" for i, j, a, b in depths)


def _placement_error(est: dict[int, Pose], true: dict[int, Pose], j: int, i: int) -> float:
    """m: the error of ASR i's frame seen from ASR j's, estimated against true."""
    e, t = between(tuple(est[j]), tuple(est[i])), between(true[j], true[i])
    return math.hypot(e[0] - t[0], e[1] - t[1])
