"""Parameters of the mapper core (method.md §1, §2, §3, §6): one frozen dataclass, SI units.

Every field says its unit and why it has its default. The defaults fit a Pioneer 2DX with a
SICK LMS200 (180°, 1° or 0.5°, cm mode); for recorded logs whose ranges are already relative to
the robot centre (the Intel and CSAIL CARMEN logs, ``robot_frontlaser_offset 0.0``) pass
``laser_x=0.0, laser_y=0.0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mapper.cycle_params import CycleParams
from mapper.limits import field_range


@dataclass(frozen=True, slots=True)
class MapperParams:
    # --- robot and sensor ----------------------------------------------------------------------
    #: m. The narrowest gap the robot passes: a P2DX is 425 mm wide; 0.60 m leaves ~9 cm a side for
    #: localisation error and the controller. Narrower gaps (chair legs, table legs) close the view.
    passage_width: float = 0.60
    #: m, robot frame. Laser mounting offset forward of the wheel axle: 17 mm on a P2DX.
    laser_x: float = 0.017
    #: m, robot frame. Laser mounting offset to the left: 8 mm on a P2DX.
    laser_y: float = 0.008
    #: rad. Laser yaw relative to the robot (forward-facing mount).
    laser_theta: float = 0.0
    #: m. Readings below this are the scanner's error codes (0 = dazzle/no echo), not surfaces.
    min_range: float = 0.02
    #: m. How far behind the robot centre the unseen rear of a view is closed: about half a P2DX
    #: length, so the robot's own footprint (which is free space) lies inside every view polygon.
    rear_closure: float = 0.20

    # --- §1 line extraction ----------------------------------------------------------------------
    #: rad. Borges & Aldon's lambda: the shallowest incidence angle at which a surface is still
    #: believed continuous. 10° is their value; it keeps oblique walls whole at long range.
    breakpoint_lambda: float = math.radians(10.0)
    #: m. Range noise sigma of the SICK LMS200 (±15 mm systematic, ~5 mm statistical at 1σ;
    #: 10 mm covers cm-mode quantisation). Enters the breakpoint distance as 3 sigma.
    breakpoint_sigma: float = 0.01
    #: m. Floor of the breakpoint distance: neighbouring points closer than this never break,
    #: whatever the range (a few cm: the beam spot and the quantisation at short range).
    breakpoint_floor: float = 0.05
    #: m. Split a piece at its farthest point when that point is farther than this from the chord:
    #: 5 cm is ~3 sigma of the range noise plus cm quantisation, so noise never splits a wall.
    split_threshold: float = 0.05
    #: rad. Neighbouring pieces of one cluster merge when their directions differ by less than this.
    merge_angle: float = math.radians(4.0)
    #: m. ...and the shared end lies within this of the other piece's line.
    merge_distance: float = 0.04
    #: m. Neighbouring pieces of one cluster are joined at their lines' intersection (a corner) when
    #: it lies within this of both their ends: about two beam spacings at 4 m (1°).
    corner_snap: float = 0.15
    #: m. A surface made of a single point (a chair leg) is drawn as a segment this long across the
    #: beam, so it still blocks sight and passage; about a table leg's diameter.
    point_surface_length: float = 0.04

    # --- §2 exits and the view polygon --------------------------------------------------------------
    #: m. Two exits of one view whose endpoints agree to within this are the same exit (the doorway
    #: found from each jamb).
    exit_merge_distance: float = 0.10
    #: m. Tolerance of the visibility tests: a surface endpoint closer than this to an exit line
    #: counts as on it (TLS endpoints scatter by about the range noise).
    visibility_tolerance: float = 0.03

    # --- §3 growing an ASR ------------------------------------------------------------------------
    #: m. Simplification tolerance of the ASR polygon: a few cm, the range noise, so wall fits from
    #: different viewpoints do not pile up zig-zag vertices.
    simplify_tolerance: float = 0.03
    #: m. A boundary edge within this of a stored exit (surface) segment, and parallel to it, gets
    #: that label; three simplify tolerances absorb the fit differences between viewpoints.
    label_tolerance: float = 0.10
    #: m. A scan becomes a new viewpoint of the ASR (its view is unioned in) once the robot has
    #: moved this far since the last viewpoint: closer views add almost no area, so this bounds the
    #: per-scan cost without losing coverage.
    view_spacing: float = 0.25
    #: rad. ...or turned this far (a turn in place reveals new sectors without moving).
    view_turn: float = math.radians(15.0)
    #: m. The robot has left its ASR, even without crossing an exit, once it is this far outside
    #: the polygon: half a passage width, beyond localisation jitter at the boundary.
    leave_margin: float = 0.30
    #: m. ... but right after entering an ASR only once it has been inside the polygon, or has
    #: moved this far from where it came in (a pose handed over into a drifted ASR can land just
    #: outside it; leaving again at once bounces the robot between two ASRs every scan).
    leave_settle: float = 1.0
    #: m². A new ASR whose first view is smaller than this is a *sliver* (taken on a doorway, cut
    #: off by the doorway's own exit just ahead): no entrance is opened on it, where the chord could
    #: face anywhere. A room is several m².
    sliver_area: float = 1.0
    #: m. Depth of the region beyond each exit of an ASR that later views may not grow into (the
    #: next room seen through a doorway belongs to the next ASR): a room's worth.
    gate_depth: float = 4.0
    #: m². A view that adds less area than this leaves the ASR unchanged (no relabelling, no
    #: AsrUpdated). Tiny on purpose: the sliver a later view fills at the first view's rear corner
    #: is well under 0.01 m², and leaving it would leave an ``unknown`` notch in a closed room.
    min_area_gain: float = 1e-4
    #: m. A duplicate ASR (closed onto an earlier one) grows at most this far beyond its match's
    #: polygon (global frame), and the match beyond its own polygon when first matched: the
    #: alignment error of a verified closure, and a little more.
    duplicate_margin: float = 0.5
    #: Upper bound on the viewpoints kept per ASR (for the record and the localisation reference);
    #: the polygon itself is grown incrementally, so its cost does not depend on this.
    max_viewpoints: int = 200

    # --- §6 localisation --------------------------------------------------------------------------
    #: Recent viewpoint scans of the ASR used as the matching reference (plus the ASR's first scan,
    #: which anchors the frame). More smooths noise; fewer follows the latest views.
    reference_scans: int = 4
    #: rad. Bin of the angle histogram: Röfer's 1°.
    angle_bin: float = math.radians(1.0)
    #: m. Bin of the x/y position histograms: 5 cm, about the range noise plus quantisation.
    xy_bin: float = 0.05
    #: m. Neighbouring scan points farther apart than this give no direction (they straddle a gap).
    direction_max_gap: float = 0.30
    #: rad. Rotation search window around the prediction: ±10° is far more than odometry drifts
    #: between two scans and well inside the 90° ambiguity of rectangular rooms.
    max_rotation: float = math.radians(10.0)
    #: m. Translation search window around the prediction, each axis.
    max_translation: float = 0.40
    #: Correlation quality (0..1, normalised cross-correlation peak) below which a match is rejected.
    min_quality: float = 0.35
    #: bins, fraction. A translation axis counts only as much as its correlation peak stands out:
    #: 1 - (the best shift at least ``prominence_bins`` bins from the peak) / (the peak), with
    #: ``prominence_full`` and above counting fully (the quality is multiplied by it). Along a
    #: corridor the correlation is nearly flat and the axis is then left to odometry.
    prominence_bins: int = 3
    prominence_full: float = 0.5
    #: Each scan point counts on a translation axis by the component of its surface's normal on
    #: it (a wall along the axis tells nothing about it); an axis whose points' mean weight is
    #: below this counts proportionally less (the quality is multiplied by mean / this).
    axis_info_full: float = 0.2
    #: m, rad. Measurement noise (1 sigma) of a perfect match (quality 1); it grows as 1/quality.
    match_sigma_xy: float = 0.04
    match_sigma_theta: float = math.radians(1.0)
    #: Odometry noise: translation sigma per metre travelled (m/m) and rotation sigma per radian
    #: turned (rad/rad), plus a small floor per scan (m, rad); typical of a differential drive.
    odom_sigma_per_m: float = 0.05
    odom_sigma_per_rad: float = 0.05
    odom_sigma_floor_xy: float = 0.005
    odom_sigma_floor_theta: float = math.radians(0.5)
    #: Squared Mahalanobis gate on the innovation (chi² with 3 dof at 99.9 %: 16.3). A match that
    #: disagrees more with the prediction is rejected as a false peak.
    gate_chi2: float = 16.3
    #: Refine a scan's pose by ICP against the reference before it becomes a viewpoint (see
    #: :mod:`mapper.localise`, "Viewpoint refinement"). Off, a viewpoint keeps the histogram
    #: match's pose (the paper's localisation), whose errors the ASR's later references inherit.
    refine: bool = True
    #: m. ICP's correspondence gate shrinks from ``refine_start`` (about the histogram match's
    #: worst error) to ``refine_inlier`` (range noise plus a wall's thickness in a scan) over at
    #: most ``refine_iterations`` steps. 12: on Intel raw and MIT CSAIL (cycle closing off) 8, 10,
    #: 12 and 20 steps gave the same relative pose error within run-to-run scatter (Intel over
    #: 20 m: 0.83, 0.79, 0.72, 0.87 m), and each step is a kd-tree query (about half the cost).
    refine_start: float = 0.30
    refine_inlier: float = 0.08
    refine_iterations: int = 12
    #: Fraction of the scan's points that must end within ``refine_inlier`` of the reference: less
    #: means the scan sees mostly what the reference did not (a new room), and ICP would guess.
    refine_min_inliers: float = 0.6
    #: m. The reference scans are densified to a point every this along their surfaces for ICP
    #: (see :func:`mapper.localise._densify`): well below the beams' spacing on a wall.
    refine_spacing: float = 0.02
    #: m. Floor of the point-to-plane residual used for the refinement's covariance (range noise).
    refine_sigma_floor: float = 0.01
    #: Independent points a scan's residuals count as: neighbouring beams on one wall share their
    #: errors, so the covariance of N pairs is that of this many (fewer: trusted less).
    refine_effective_points: int = 100

    # --- §4, §5, §7 topology, global metric map and cycles ----------------------------------------
    #: Cycle detection, closing and realignment (:class:`mapper.cycle_params.CycleParams`, every field
    #: documented there); ``CycleParams.paper()`` runs the paper's plain method alone.
    cycles: CycleParams = field(default_factory=CycleParams)


#: Fields in radians: a configured value of them is at most pi (a half turn).
ANGLE_FIELDS = frozenset({"breakpoint_lambda", "merge_angle", "view_turn", "angle_bin", "max_rotation",
                          "match_sigma_theta", "odom_sigma_floor_theta"})
#: Ranges of their own: the laser's mounting offsets (m, m, rad in the robot frame), which may be
#: negative, and the histograms' bins, whose cell counts grow with the inverse square (a
#: 1.7e-5 rad angle bin allocates 27 GB).
OWN_LIMITS = {"laser_x": (-2.0, 2.0), "laser_y": (-2.0, 2.0), "laser_theta": (-math.pi, math.pi),
              "angle_bin": (math.radians(0.1), math.radians(10.0)), "xy_bin": (0.005, 0.5)}


def limits(name: str) -> tuple[float, float]:
    """The closed range a configured value of :class:`MapperParams` field ``name`` must lie in:
    its own (:data:`OWN_LIMITS`), else :func:`mapper.limits.scaled_range` of its default (an angle,
    :data:`ANGLE_FIELDS`, at most pi). Probed at both ends of every range with 800 Intel raw scans:
    the mapper runs, if slowly at the extremes (12,000 refinement iterations: 12 ms a scan); beyond
    them a 1e-9 m translation bin or a laser 1e9 m away raised MemoryError."""
    return field_range(MapperParams(), name, own=OWN_LIMITS, angles=ANGLE_FIELDS)
