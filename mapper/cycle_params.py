"""Parameters of the topological map, the global metric map and cycle closing.

The paper's plain method (method.md §5) is :meth:`CycleParams.paper`: every extension of §7 off.
The defaults switch the extensions on. Units: metres, radians, m², fractions in 0..1.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from mapper.limits import field_range


@dataclass(frozen=True, slots=True)
class CycleParams:
    """Switches and thresholds of cycle detection and closing (frozen; replace() to change)."""

    enabled: bool = True
    """Run the cycle check at all. Off: a pure topological map with a drifting global map."""

    regrowth_fraction: float = 0.25
    """Re-check the current ASR when its area grew by more than this fraction (of the area at
    its last check). The paper re-checks a growing ASR so that a match rejected early (ASR6/ASR7)
    can pass later; 25 % keeps the number of checks per ASR small (about log(area) of them)."""

    leave_check: bool = True
    """Beyond the paper: check the current ASR once more as the robot leaves it, when it grew at all
    since its last check (by less than ``regrowth_fraction``). The paper checks at creation and as
    the ASR grows; a revisit whose centres come inside each other only in the ASR's last views
    was refused at its last check and never looked at again (stepped ``lab``: of the revisits
    missed, all but one were refused by the centre crosscheck with 0.01-0.16 m of drift)."""

    entry_hysteresis: float = 0.3
    """m. After entering an ASR through exit f, crossing f again does not count until the robot has
    been this far from f: standing on a doorway, localisation noise would otherwise flip the robot
    between the two ASRs on every scan. Half a passage width."""

    min_area: float = 1.0
    """m². ASRs smaller than this are not checked: a sliver seen through a doorway has a centre
    that lands anywhere and would cause a chance match."""

    exclude_hops: int = 1
    """Candidates this many topological hops or fewer from the current ASR are excluded. The paper
    excludes the current ASR and the one it was entered from (1). Beyond the paper, 2 also skips
    the ASR two transitions back, which overlaps the current one in a corridor without any cycle."""

    crosscheck_margin: float = 0.3
    """m. Beyond the paper: each centre must lie this far inside the other polygon, not merely inside.
    A centre near the other's boundary is where drift and the ragged outline of real ASRs (spikes
    seen through gaps) decide, not the place; 0 is the paper's test."""

    verify_crosscheck_margin: float = 0.3
    """m. Beyond the paper (needs ``verify``): the crosscheck repeated with the verified surface
    alignment applied asks each centre to lie this far inside the other polygon (at most
    ``crosscheck_margin``), when the unaligned crosscheck has already passed with the full margin;
    a candidate found by ``search_radius`` alone always needs ``crosscheck_margin`` aligned. The
    margin guards against drift, and the alignment has placed the two ASRs by their walls, so less
    could do. Measured with 0.1: of the stored alignments on the five shared logs that failed only
    the aligned crosscheck at 0.3 m, every false one (by truth) left a centre outside the other ASR
    once aligned, while true ones kept both 0.15-0.26 m inside; Intel corrected gained two true
    closures and no log a false one. But in the simulated runs it moved four runs and one (``lab``
    seed 2) no longer finished exploring within the hour (so again once the explorer's cache fault
    that made runs depend on memory layout was fixed), so the default stays at
    ``crosscheck_margin``'s 0.3. (Applied to the search-radius candidates too, 0.1 let a false
    closure through in ``lab`` seed 4, aligned 1.75 m off.)"""

    hold_crosscheck: bool = True
    """Beyond the paper: an accepted cycle keeps holding as its two ASRs grow. A view that would
    leave either centre less than ``crosscheck_margin`` inside the other ASR's polygon (global
    frame), or less deep than it was, is not unioned into the ASR (``Mapper._keep_closed_places``):
    the robot leaves it as it leaves any ASR, into a new one. A duplicate that grew on past the
    place it was matched as had its centre move out of its match (lab world: 0.4-0.6 m inside at
    acceptance, 0.15-0.2 m outside at the end, in truth as in the map)."""

    search_radius: float = 2.0
    """m. Beyond the paper (needs ``verify``): ASRs whose global polygon comes within this distance of
    the current centre without containing it are aligned by their surfaces, and become candidates if
    the crosscheck passes with the alignment applied (reason ``aligned-crosscheck``). Recovers
    revisits whose centre drift pushed just outside the earlier ASR. 0: the paper's candidates only."""

    near_earlier_only: bool = True
    """Beyond the paper: a ``search_radius`` candidate (reason ``aligned-crosscheck``) is tried only
    when it was made before the ASR checked. An ASR re-entered and grown is checked again against
    the ASRs made after it, pairs already tried the other way round when the later one was new:
    a second draw of the one test. In 60 stepped ``lab`` runs of an explorer that drove the lab's
    corridors in other orders, both closures so made were false (an old corridor piece, re-entered,
    aligned onto a later piece beside it; by the truth each centre lay 0.75 m outside the other in
    one, 5 mm in the other); every true one, 12 over those and other experiments' runs and 3 on
    the logs, was onto an earlier ASR. False: tried both ways."""

    align_failed_crosscheck: bool = True
    """Beyond the paper (needs ``verify``): a candidate containing the current centre whose own centre
    fails the crosscheck is aligned by its surfaces as a ``search_radius`` candidate is, and held to
    the same rules (the crosscheck with the alignment applied, ``verify_min_constraint``,
    ``verify_near_min_inliers``; reason ``realigned-crosscheck``). It lies nearer than such a
    candidate: drift of a metre or two (Intel raw: 1.6-2.1 m) fails the crosscheck of revisits
    whose surfaces say where they are. Off: every such candidate is rejected, as in the paper."""

    hindsight: bool = True
    """§7: when ASR k matches j, accept earlier rejected pairs (a, b) (by the crosscheck, or by
    verification) where a lies within ``hindsight_hops`` links of k and b of j (the paper's
    ASR6/ASR7 case, in hindsight)."""

    hindsight_hops: int = 2
    """How many topological hops counts as "neighbour" for hindsight acceptance: a rejected pair
    (a, b) is re-examined when k matches j with a within this many links of k and b of j. The
    paper's case is 1 (the ASRs next to the match). With 2, a revisit refused with an ASR between
    it and the next match is re-examined too (the pair still has to pass the crosscheck with the
    match's correction applied and its own verification): stepped ``lab`` seed 30 left a loop open
    with ASR 34 refused against 13 (13's centre 0.12 m inside 34 by the truth) while 35, entered
    from 34, matched 19, two links from 13. Over ``lab`` 0-39 against 1: whole goal 28 against 25
    runs, revisits missed 67 of 816 against 87 of 806, no false closure (nor in ``office`` and
    ``aliasing`` 0-9); the five logs unchanged."""

    hindsight_margin: float = 0.1
    """m. Beyond the paper (needs ``verify``): the crosscheck margin asked of a pair re-examined in
    hindsight, at most ``crosscheck_margin``. Its neighbours on both sides have just been matched
    (and verified), the correction of that match applied, and the pair must still verify by its
    own surfaces: a shallow revisit beside an accepted one (``lab`` seed 1: ASR 30's centre 0.20 m
    inside ASR 6, the next ASR, 31, matched 5, the ASR before 6) is the same place, not drift."""

    verify: bool = True
    """§7: confirm a match by aligning the two ASRs' surfaces (ICP on points sampled along their
    ``surface`` edges, in the global frame) and requiring a low residual."""

    verify_max_residual: float = 0.15
    """m. Largest RMS point-to-nearest-point distance of the matched surface points after ICP.
    Wall points of one place re-seen from another viewpoint agree to a few cm; 15 cm tolerates
    segment fitting noise of both ASRs."""

    verify_min_inliers: float = 0.4
    """Fraction of the smaller ASR's surface points that must lie within ``verify_inlier_distance``
    of the other ASR's surfaces after alignment. Two different places rarely share 40 % of walls."""

    verify_inlier_distance: float = 0.2
    """m. A surface point is an inlier when its nearest surface point of the other ASR is this close."""

    verify_max_correction: float = 2.0
    """m. The ICP correction may move the current ASR this far at most (as far as ``search_radius``
    looks): beyond it the alignment found is more likely another local minimum than the drift."""

    verify_max_rotation: float = 0.5
    """rad. Largest rotation ICP may apply (same reason as ``verify_max_correction``)."""

    verify_max_violation: float = 0.05
    """Largest fraction of either ASR's surface points that may lie inside the other's free space
    after alignment. Two views of one place never see a wall where the other saw through; two
    similar but different places (or a wrong alignment) do."""

    verify_crosschecked_violation: float = 0.2
    """The largest free-space violation (as ``verify_max_violation``) of a candidate whose unaligned
    centre crosscheck passed with the full ``crosscheck_margin`` (each centre that deep inside the
    other ASR by dead reckoning alone: the paper's evidence of one place) and whose alignment has
    at least ``verify_near_min_inliers`` of its surface points agreeing and is fixed in every
    direction (``verify_constrained``). A cluttered room seen from two viewpoints (tables, chair
    legs the simplified polygons cut across) leaves 5-19 % of points in the other's free space:
    traced in stepped ``lab`` (seeds 5, 13, 20) every such refusal was a true revisit of the lab
    room, centres 2-3.3 m inside each other, 50-67 % inliers at 2-4 cm RMS, constraint 0.13-0.49.
    The conditions keep the check where it is the evidence: CSAIL corrected's two false matches
    that only the violation refuses (6 % and 10 %) have 41-43 % inliers at 8-11 cm, and a straight
    corridor piece (its alignment open along the corridor, placed by the drift bound or the
    topology) slid onto its neighbour sees the corridor's end or a door jamb in the other's free
    space (stepped ``lab`` seed 18, 20 onto 4: 27 % refused, then 20 % accepted, false).
    ``verify_max_violation`` or less: as strict as the rest."""

    verify_min_constraint: float = 0.15
    """Smallest eigenvalue (0..0.5) of the matched surfaces' normal scatter, required of a candidate
    found only by ``search_radius`` (its alignment is the only evidence). Along a straight corridor
    (all normals parallel, ~0) an alignment says nothing about the position along it, so it cannot
    make a match; an L-corner or a room gives 0.2-0.5."""

    verify_constrained: float = 0.05
    """Smallest eigenvalue (0..0.5) of the matched surfaces' normal scatter required of every
    verified match (``verify_min_constraint``, stricter, is required of one found only by
    ``search_radius``). Along a straight corridor the surfaces say nothing about where along it the
    two ASRs lie, so the match rests on the drifting map alone: in the lab world the matches with
    0-0.007 were placed 0.5-6 m off along the corridor, and every false closure of three seed-0
    runs was one; those with 0.03 or more were 0.01-0.16 m off. A dead end's wall (2 m across a
    6 m piece: 0.14) is enough. The corner or room next to a straight piece closes the cycle
    instead. 0: no requirement (verification as before)."""

    topological_anchor: bool = True
    """Beyond the paper (needs ``verify``): a match ``verify_constrained`` would refuse (a straight
    corridor piece) is accepted when the topology anchors it: a neighbour of the new ASR (the one
    the robot came from, say) is, by an accepted cycle, the same place as a different neighbour of
    the candidate. Along a corridor the alignment cannot say where the two pieces lie; the closure
    beside them can. Tested at the check and in hindsight (a piece met before its corner is closed
    when the corner closes). Not for ``search_radius`` candidates. In the simulated worlds (22 runs)
    missed revisits 85 of 245 -> 78 of 249 with no false closure; Intel corrected one more true
    closure. Off: such pieces stay unclosed."""

    drift_bound_sigmas: float = 2.0
    """Beyond the paper (needs ``verify``): a match ``verify_constrained`` would refuse (a straight
    corridor piece, whose alignment leaves the position along it open) is accepted when the drift
    along that open axis is bounded: with the alignment applied, each centre can move at least this
    many standard deviations along the axis and stay inside the other ASR. The standard deviation is
    the pose graph's (odometry and loop edges, ``odometry_sigma_xy`` and the rest): how far ``n``
    may lie from ``m`` along the axis after the chain of transitions and the loops closed between
    them (:func:`mapper.posegraph.relative_covariance`). Not for ``search_radius`` candidates
    (their only crosscheck is the aligned one). 0: off (such pieces need ``topological_anchor``)."""

    exit_pin_sigmas: float = 2.0
    """Beyond the paper (needs ``verify``): an alignment whose surfaces leave the position along
    them open (``verify_constrained`` not met: a straight corridor piece) is moved along that axis
    so that the exits of the two ASRs meet (doorways in the corridor's walls, its ends), and then
    counts as constrained (:func:`mapper.cycles.exit_pin`). The exits must agree within
    ``verify_inlier_distance``, and the shift must be the only one within this many of the pose
    graph's standard deviations along the axis (as ``drift_bound_sigmas``; at most
    ``verify_max_correction``): a row of like doorways closer than the drift cannot pin. 0: off."""

    verify_min_across: float = 0.5
    """m. Beyond the paper (needs ``verify``): a match whose surfaces leave the position along them
    open (``verify_constrained`` not met), accepted by ``exit_pin_sigmas``, ``topological_anchor``
    or ``drift_bound_sigmas``, must be carried by surfaces at least this far apart across that axis
    (:attr:`mapper.cycles.Alignment.across`): both walls of a corridor, not one wall. One wall
    matches any wall facing the same way, at any offset along it: in the lab world two of the six
    false closures of 60 runs were such matches (a closure 1.5-1.8 m wrong), with a residual of
    exactly 0. A corridor a Pioneer can pass is at least the passage width (0.6 m) across. 0: off."""

    near_drift_sigmas: float = 4.0
    """Beyond the paper (needs ``verify``): a candidate found only by ``search_radius`` (or whose
    crosscheck the drift failed) is refused when its alignment moves the new ASR's centre farther
    than this many of the pose graph's standard deviations of the one ASR relative to the other,
    along the move (as ``drift_bound_sigmas``): a chi-square gate in one dimension. Two ASRs a few
    transitions apart cannot have drifted metres apart; aligned onto each other anyway, one is a
    neighbouring place of like shape. Measured: ``office`` seed 4's false 16 onto 13 (a room aligned
    1.8 m onto the corridor beside it) moved 10.8 sigma, and with a 3 m search radius Intel
    corrected's false 40 onto 38 4.7 sigma; the true ones on the five logs moved 0.2-3.9 sigma
    (Intel raw's 34 onto 19: 3.9). 0: off."""

    verify_parent: bool = True
    """Beyond the paper (needs ``verify``): a candidate found only by ``search_radius`` (or whose
    crosscheck the drift failed) is refused when the ASR the new one was entered from, moved by the
    same alignment, sees surfaces in the match's free space or the match sees surfaces in its own
    (more than ``verify_max_violation`` of either's surface points, ``verify_free_space_margin``
    deep). That ASR adjoins the new one, so if the new one is the match it adjoins the match too.
    A room aligned onto a like one next door brings its corridor piece into that room: ``office``
    seed 0's false 20 onto 16 (1.8 m, 3.6 sigma, every surface agreeing) left 13.6 % of its
    corridor piece's points so, where the true aligned matches on the logs (Intel raw's 18 onto 2
    and 34 onto 19, MIT CSAIL's 47 onto 42) left none."""

    verify_near_min_inliers: float = 0.5
    """Fraction of inliers (as ``verify_min_inliers``) required of a candidate found only by
    ``search_radius``: with no crosscheck behind it, half its surfaces must agree. On MIT CSAIL a
    corridor piece aligned at 46 % onto its neighbour 1.6 m away, a false closure; the true ones
    found this way had 54-77 %."""

    verify_free_space_margin: float = 0.3
    """m. How deep inside the other polygon a surface point must lie to count as a violation:
    above alignment and simplification error, below a door jamb's depth."""

    sample_spacing: float = 0.05
    """m. Spacing of the points sampled along surface edges for ICP."""

    realign: bool = True
    """§7: relax the ASR-level pose graph after every accepted cycle (MapRealigned)."""

    odometry_sigma_xy: float = 0.05
    """m per metre travelled (plus a 5 cm floor). Standard deviation of an odometry edge's
    translation between consecutive ASRs: wheel odometry drifts a few cm per metre."""

    odometry_sigma_theta: float = 0.03
    """rad per metre travelled (plus a 0.01 rad floor): the heading drift of odometry edges."""

    loop_sigma_xy: float = 0.1
    """m. Standard deviation of a loop edge's translation (ICP alignment of two ASRs) along an axis
    the aligned surfaces constrain (``loop_constraint_full``): a few cm of alignment error, doubled."""

    loop_sigma_theta: float = 0.05
    """rad. Standard deviation of a loop edge's rotation."""

    loop_constraint_full: float = 0.15
    """Smallest eigenvalue (0..0.5) of a verified alignment's normal scatter along an axis for the
    loop edge to carry ``loop_sigma_xy`` along it; less, and its information there falls in
    proportion down to an unverified edge's (``GlobalMap._loop_info``). The same figure as
    ``verify_min_constraint``: an L-corner or a room gives 0.2-0.5, a straight corridor ~0."""

    loop_sigma_unverified_xy: float = 1.0
    """m. A loop edge without an ICP alignment only says the two centres coincide: loose."""

    loop_sigma_unverified_theta: float = 3.0
    """rad. Rotation of an unverified loop edge is unobserved: effectively free."""

    posegraph_iterations: int = 20
    """Largest number of Gauss-Newton iterations per realignment (it converges in 3-6)."""

    @classmethod
    def paper(cls) -> CycleParams:
        """The paper's plain method: crosscheck and best overlap, no hindsight/verification/realignment."""
        return cls(
            hindsight=False,
            leave_check=False,
            hold_crosscheck=False,
            verify=False,
            realign=False,
            exclude_hops=1,
            crosscheck_margin=0.0,
            search_radius=0.0,
            align_failed_crosscheck=False,
        )

    def replace(self, **changes) -> CycleParams:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


#: Ranges of their own: the surfaces' sampling for alignment, whose point count grows with its
#: inverse (5e-5 m: no replay of Intel raw ended within 2 minutes).
OWN_LIMITS = {"sample_spacing": (0.005, 0.5)}
#: Fields that a division or a geometric sequence needs above 0 (noise figures, a distance scale).
POSITIVE_FIELDS = frozenset({"verify_inlier_distance", "odometry_sigma_xy",
                             "odometry_sigma_theta", "loop_sigma_xy", "loop_sigma_theta",
                             "loop_constraint_full", "loop_sigma_unverified_xy",
                             "loop_sigma_unverified_theta"})
#: Fields in radians: a configured value of them is at most pi.
ANGLE_FIELDS = frozenset({"verify_max_rotation", "odometry_sigma_theta", "loop_sigma_theta",
                          "loop_sigma_unverified_theta"})


def limits(name: str) -> tuple[float, float]:
    """The closed range a configured value of :class:`CycleParams` field ``name`` must lie in: its
    own (:data:`OWN_LIMITS`), else :func:`mapper.limits.scaled_range` of its default: from 0, where
    0 means something (a margin or a radius of 0 is the paper's test), else from a thousandth of
    the default (:data:`POSITIVE_FIELDS`: a sigma of 0 divided by zero in the pose graph). Probed at
    both ends of every range with a replay of Intel raw (2.5 s at the defaults): each ran, the
    slowest in 22-26 s (``loop_constraint_full`` 150, ``sample_spacing`` 0.005: still 42x real
    time)."""
    return field_range(CycleParams(), name, own=OWN_LIMITS, angles=ANGLE_FIELDS,
                       zero=name not in POSITIVE_FIELDS)
