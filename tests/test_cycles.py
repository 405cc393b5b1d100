"""Cycle detection and closing on constructed ASRs (method.md §5 and §7)."""

import dataclasses
import math

import numpy as np
import pytest

from mapper.cycle_params import CycleParams
from mapper.cycles import Alignment, SpatialIndex, align_points, exit_pin
from mapper.events import CycleDetected, CycleRejected, MapRealigned
from mapper.globalmap import GlobalMap, _unslid
from mapper.se2 import between, compose, transform_points
from mapper.types import Exit
from tests.synthetic_asrs import box_asr, drift, drive

PAPER = CycleParams.paper()
FULL = CycleParams()

# A corridor 2 m wide around a 6 m x 6 m block: south, east, north, west sides, then south again.
LOOP = [
    ((0, 0, 10, 2), (1.0, 1.0, 0.0), "EN"),
    ((8, 0, 10, 10), (9.0, 1.0, math.pi / 2), "SN"),
    ((0, 8, 10, 10), (9.0, 9.0, math.pi), "EW"),
    ((0, 0, 2, 10), (1.0, 9.0, -math.pi / 2), "NS"),
    ((0, 0, 10, 2), (1.0, 1.0, 0.0), "EN"),
    ((8, 0, 10, 10), (9.0, 1.0, math.pi / 2), "SN"),
]


def accepted(events):
    return [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleDetected)]


UNANCHORED = FULL.replace(topological_anchor=False, drift_bound_sigmas=0.0, exit_pin_sigmas=0.0)


@pytest.mark.parametrize("params", [PAPER, FULL, UNANCHORED, UNANCHORED.replace(drift_bound_sigmas=2.0),
                                    UNANCHORED.replace(exit_pin_sigmas=2.0)],
                         ids=["paper", "extended", "extended-unanchored", "extended-drift-bound",
                              "extended-exit-pin"])
def test_corridor_loop_revisit_is_detected_with_no_false_cycle(params):
    gm = GlobalMap(params)
    events = drive(gm, LOOP, per_step=(0.15, -0.1, 0.02))
    if params == UNANCHORED:
        # ASR 2 is a straight piece (walls east and west only): the alignment cannot say where
        # along it 6 lies, so without the topological anchor extended mode leaves it unclosed.
        assert accepted(events) == [(5, 1, "centre-crosscheck")]
        assert any(isinstance(e, CycleRejected) and (e.asr, e.matches, e.reason) == (6, 2, "verification")
                   for e in events)
    else:
        # Extended mode: 6 was entered from 5, which closed onto 1, a neighbour of 2; so 6 is the
        # piece beside 1 (topological_anchor), which its walls alone cannot say. Without the
        # anchor, the pose graph says the same (drift_bound_sigmas): through the loop edge 5 -> 1,
        # 6 lies one 10 m transition from 2, well within the 10 m piece. And without either, the
        # exits do (exit_pin_sigmas): the piece's ends, aligned, say where along it 6 lies.
        assert accepted(events) == [(5, 1, "centre-crosscheck"), (6, 2, "centre-crosscheck")]
        assert gm.asrs[6].duplicate_of == 2
    assert gm.asrs[5].duplicate_of == 1
    # The ASR 5 was entered from (4) now leads into 1 through 1's nearest exit, both ways.
    t = gm.topology.lookup(4, gm.topology.entered[5].exit)
    assert t.dst == 1 and gm.topology.lookup(1, t.via).dst == 4
    assert any(ln.oneway and ln.src == 5 and ln.dst == 4 for ln in gm.topology.links)
    records = [r.to_dict() for r in gm.cycles if r.accepted]
    assert records[0]["asr"] == 5 and records[0]["matches"] == 1 and 0 < records[0]["iou"] <= 1


def test_realignment_pulls_the_drifted_loop_back_onto_the_truth():
    gm = GlobalMap(FULL)
    events = drive(gm, LOOP[:5], per_step=(0.15, -0.1, 0.02))
    assert any(isinstance(e, MapRealigned) for e in events)
    truth = {k + 1: f for k, (_, f, _) in enumerate(LOOP[:5])}

    def err(origins):
        return max(math.hypot(origins[k][0] - truth[k][0], origins[k][1] - truth[k][1]) for k in truth)

    assert err({k: a.origin for k, a in gm.asrs.items()}) < 0.3 * err(gm.odometry_origin)


ROOMS = [  # two identical 5 m x 4 m rooms joined by a 3 m corridor
    ((0, 0, 5, 4), (2.5, 2.0, 0.0), "E"),
    ((5, 1.5, 8, 2.5), (5.5, 2.0, 0.0), "EW"),
    ((8, 0, 13, 4), (10.5, 2.0, 0.0), "W"),
]


@pytest.mark.parametrize("params", [PAPER, FULL], ids=["paper", "extended"])
# The last drift moves room 3 onto room 1 until their polygons overlap, but not their centres.
@pytest.mark.parametrize("drift", [(0.0, 0.0, 0.0), (-0.5, 0.3, 0.05), (-1.0, -0.4, -0.08), (-2.0, 0.3, 0.0)])
def test_identical_rooms_in_different_places_do_not_close_a_cycle(params, drift):
    gm = GlobalMap(params)
    events = drive(gm, ROOMS, per_step=drift)
    assert accepted(events) == []
    assert all(a.duplicate_of is None for a in gm.asrs.values())


# Room 1 with a dead-end corridor east (2); around a loop (3, 4, 5) the robot re-enters the room
# from the west (6), then walks into the corridor again (7). Odometry has drifted 0.15 m west per
# transition: 6 (the room's western 2.6 m) is misplaced so that its centre lies in 1 but 1's centre
# not in 6 (crosscheck fails); 7 matches 2, and the corridor's end wall tells how far the map drifted.
HINDSIGHT = [
    ((0, 0, 4, 4), (2.0, 2.0, 0.0), "E"),
    ((4, 1, 10, 3), (4.5, 2.0, 0.0), "W"),
    ((10, 1, 12, 9), (11.0, 2.5, math.pi / 2), "SN"),
    ((0, 7, 12, 9), (11.0, 8.0, math.pi), "EW"),
    ((-2, 1, 0, 9), (-1.0, 8.0, -math.pi / 2), "NS"),
    ((0, 0, 2.6, 4), (0.5, 2.0, 0.0), "E"),
    ((4, 1, 10, 3), (4.5, 2.0, 0.0), "W"),
]
WEST = (-0.15, 0.0, 0.0)


@pytest.mark.parametrize("leave_check", [True, False])
def test_a_revisit_that_passes_only_after_its_last_growth_check_is_closed_as_the_robot_leaves(leave_check):
    # ASR 6, the room's western 2.6 m placed 0.75 m west by the drift, fails the crosscheck at
    # creation (1's centre, x = 2, is 1.85 m in global x: only 0.1 m inside 6). It then grows to
    # 3.2 m (23 %, below regrowth_fraction: no check), which puts 1's centre 0.45 m inside; the
    # robot leaves for 7, and the leave check closes 6 onto 1. Without it, nothing does.
    params = FULL.replace(align_failed_crosscheck=False, hindsight=False, leave_check=leave_check)
    gm = GlobalMap(params)
    events = drive(gm, HINDSIGHT[:6], per_step=WEST)
    assert (6, 1, "centre-crosscheck") in [(e.asr, e.matches, e.reason) for e in events
                                           if isinstance(e, CycleRejected)]
    _, frame, exits = HINDSIGHT[5]
    grown = box_asr(6, (0, 0, 3.2, 4), frame, exits)
    gm.asrs[6].boundary, gm.asrs[6].centre = grown.boundary, grown.centre
    assert gm.updated(6, 6.5) == []  # grew by less than regrowth_fraction: no check
    seven = box_asr(7, *HINDSIGHT[6][:1], HINDSIGHT[6][1], HINDSIGHT[6][2])
    crossing = between(compose(drift(5, WEST), frame), compose(drift(6, WEST), HINDSIGHT[6][1]))
    events = gm.add_created(seven, 6, gm.asrs[6].exits[0].id, seven.exits[0].id, crossing, 7.0)
    if leave_check:
        assert (6, 1, "centre-crosscheck") in accepted(events)
        assert gm.asrs[6].duplicate_of == 1
    else:
        assert (6, 1) not in [(a, m) for a, m, _ in accepted(events)]
        assert gm.asrs[6].duplicate_of is None


def test_a_misaligned_overlap_fails_the_crosscheck_and_is_accepted_in_hindsight():
    gm = GlobalMap(FULL.replace(align_failed_crosscheck=False))
    events = drive(gm, HINDSIGHT, per_step=WEST)
    rejected = [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)]
    assert (6, 1, "centre-crosscheck") in rejected
    assert accepted(events) == [(7, 2, "centre-crosscheck"), (6, 1, "hindsight")]
    assert gm.asrs[6].duplicate_of == 1


@pytest.mark.parametrize("margin", [0.1, 0.3])
def test_a_shallow_revisit_beside_an_accepted_one_is_closed_in_hindsight_with_the_hindsight_margin(margin):
    # 6 is the room's western 2.2 m: with the drift undone, 1's centre (x = 2) lies only 0.2 m
    # inside it, short of the 0.3 m crosscheck margin. Once 7 (entered from 6) matches 2 (entered
    # from 1), hindsight asks hindsight_margin: 0.1 m closes 6 onto 1 (its walls verify it), the
    # full 0.3 m leaves it open, as before the margin existed.
    route = [*HINDSIGHT[:5], ((0, 0, 2.2, 4), (0.5, 2.0, 0.0), "E"), HINDSIGHT[6]]
    gm = GlobalMap(FULL.replace(align_failed_crosscheck=False, hindsight_margin=margin))
    events = drive(gm, route, per_step=WEST)
    assert (6, 1, "centre-crosscheck") in [(e.asr, e.matches, e.reason) for e in events
                                           if isinstance(e, CycleRejected)]
    if margin < 0.2:
        assert accepted(events) == [(7, 2, "centre-crosscheck"), (6, 1, "hindsight")]
        assert gm.asrs[6].duplicate_of == 1
    else:
        assert accepted(events) == [(7, 2, "centre-crosscheck")]
        assert gm.asrs[6].duplicate_of is None


@pytest.mark.parametrize("hops", [1, 2])
def test_a_rejected_revisit_two_links_from_the_next_match_is_closed_in_hindsight_with_two_hops(hops):
    # As above, but between the room piece 6 and the corridor piece that matches 2 lies a doorway
    # piece too small to be checked (7, 0.8 m²): the match 8 -> 2 is two links from 6. With
    # hindsight_hops 2 (the default) hindsight re-examines (6, 1) and closes it; with the paper's
    # one hop it stays rejected.
    route = [*HINDSIGHT[:6], ((4, 1.5, 4.8, 2.5), (4.1, 2.0, 0.0), "WE"),
             ((4.8, 1, 10, 3), (4.9, 2.0, 0.0), "W")]
    gm = GlobalMap(FULL.replace(align_failed_crosscheck=False, hindsight_hops=hops))
    events = drive(gm, route, per_step=WEST)
    assert (6, 1, "centre-crosscheck") in [(e.asr, e.matches, e.reason) for e in events
                                           if isinstance(e, CycleRejected)]
    if hops == 2:
        assert accepted(events) == [(8, 2, "centre-crosscheck"), (6, 1, "hindsight")]
        assert gm.asrs[6].duplicate_of == 1
    else:
        assert accepted(events) == [(8, 2, "centre-crosscheck")]
        assert gm.asrs[6].duplicate_of is None


def test_a_revisit_whose_crosscheck_drift_fails_is_accepted_once_aligned_by_its_surfaces():
    gm = GlobalMap(FULL)
    events = drive(gm, HINDSIGHT, per_step=WEST)
    # five crossings of 0.15 m drift west: the room's walls say where the revisit lies
    assert accepted(events) == [(6, 1, "realigned-crosscheck"), (7, 2, "centre-crosscheck")]
    assert [e for e in events if isinstance(e, CycleRejected)] == []
    assert gm.alignments[(6, 1)].correction == pytest.approx((0.75, 0.0, 0.0), abs=0.02)


def test_the_paper_method_alone_leaves_the_misaligned_overlap_rejected():
    gm = GlobalMap(PAPER)
    events = drive(gm, HINDSIGHT, per_step=WEST)
    assert accepted(events) == [(7, 2, "centre-crosscheck")]
    assert gm.asrs[6].duplicate_of is None


def test_a_growing_asr_is_checked_again_and_passes_once_it_covers_the_match():
    gm = GlobalMap(PAPER)
    drive(gm, HINDSIGHT[:6], per_step=WEST)
    assert gm.asrs[6].duplicate_of is None
    small = gm.asrs[6]
    grown = box_asr(6, (0, 0, 3.5, 4), HINDSIGHT[5][1], "E")
    small.boundary, small.centre = grown.boundary, grown.centre
    events = gm.updated(6, 6.5)
    assert accepted(events) == [(6, 1, "centre-crosscheck")]
    assert gm.updated(6, 6.6) == []  # closed: no further checks


def test_several_survivors_take_the_largest_overlap_and_report_the_rest():
    route = [
        ((0, 0, 6, 2), (1.0, 1.0, 0.0), "E"),
        ((5, 0, 12, 2), (5.5, 1.0, 0.0), "WE"),
        ((12, 0, 14, 10), (13.0, 1.0, math.pi / 2), "SN"),
        ((0, 8, 14, 10), (13.0, 9.0, math.pi), "EW"),
        ((-2, 0, 0, 10), (-1.0, 9.0, -math.pi / 2), "NS"),
        ((1, 0, 10.8, 2), (1.0, 1.0, 0.0), "WE"),
    ]
    events = drive(GlobalMap(PAPER), route)
    assert accepted(events) == [(6, 2, "centre-crosscheck")]
    assert [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)] == [
        (6, 1, "lower-overlap")
    ]


def test_no_checks_when_disabled():
    events = drive(GlobalMap(CycleParams(enabled=False)), LOOP)
    assert accepted(events) == []


def test_spatial_index_answers_point_queries_after_updates_and_rebuilds():
    import shapely

    idx = SpatialIndex()
    for k in range(40):
        idx.upsert(k, shapely.box(k, 0, k + 1.5, 1))
    assert idx.containing(10.2, 0.5) == [9, 10]
    idx.upsert(10, shapely.box(100, 0, 101, 1))
    assert idx.containing(10.2, 0.5) == [9]
    assert idx.containing(100.5, 0.5) == [10]
    idx.remove(9)
    assert idx.containing(10.2, 0.5) == []
    idx.rebuild({1: shapely.box(0, 0, 1, 1)})
    assert idx.containing(0.5, 0.5) == [1] and idx.containing(10.2, 0.5) == []


def test_icp_recovers_a_small_rigid_misalignment_of_an_l_shaped_wall():
    wall = np.concatenate(
        [np.c_[np.linspace(0, 5, 100), np.zeros(100)], np.c_[np.zeros(80), np.linspace(0, 4, 80)]]
    )
    normals = np.concatenate([np.tile([0.0, 1.0], (100, 1)), np.tile([1.0, 0.0], (80, 1))])
    moved = transform_points((0.3, -0.2, 0.05), wall)
    a = align_points(moved, wall, normals, inlier_distance=0.05)
    assert a.rms < 0.01 and a.inliers > 0.95
    back = transform_points(a.correction, moved)
    assert np.max(np.hypot(*(back - wall).T)) < 0.01
    assert between(a.correction, (0, 0, 0))[2] == pytest.approx(0.05, abs=1e-3)


def test_icp_measures_how_far_apart_across_a_corridor_its_matched_walls_lie():
    # A corridor 2 m wide along x: both walls match, 2 m across its axis; the south wall alone, 0.
    n = 100
    south = np.c_[np.linspace(0, 6, n), np.zeros(n)]
    north = np.c_[np.linspace(0, 6, n), np.full(n, 2.0)]
    walls = np.concatenate([south, north])
    normals = np.concatenate([np.tile([0.0, 1.0], (n, 1)), np.tile([0.0, -1.0], (n, 1))])
    both = align_points(transform_points((0.1, 0.05, 0.02), walls), walls, normals, 0.05, p_normals=normals)
    one = align_points(transform_points((0.1, 0.05, 0.02), south), walls, normals, 0.05,
                       p_normals=normals[:n])
    assert both.constraint < 0.01 and both.across == pytest.approx(2.0, abs=0.05)
    assert one.constraint < 0.01 and one.across < 0.01


def test_hindsight_does_not_accept_a_mere_partial_overlap():
    # 6 sees only the room's western strip: its centre lies in 1 but 1's centre is outside 6 even
    # with the drift undone, so the two are not the same place and stay apart.
    route = [*HINDSIGHT[:5], ((0, 0, 1.5, 4), (0.5, 2.0, 0.0), "E"), HINDSIGHT[6]]
    events = drive(GlobalMap(FULL), route, per_step=(0.05, 0.0, 0.0))
    assert (6, 1, "centre-crosscheck") in [
        (e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)
    ]
    assert accepted(events) == [(7, 2, "centre-crosscheck")]


# A 3 m x 4 m room left north into a corridor and entered again from it, with 1.8 m of drift east:
# the revisit's centre falls just outside the room, so the paper's check has no candidate.
RETURN = [
    ((0, 0, 3, 4), (1.5, 2.0, math.pi / 2), "N"),
    ((0.5, 4, 2.5, 10), (1.5, 4.5, math.pi / 2), "SN"),
    ((0, 0, 3, 4), (1.5, 3.5, -math.pi / 2), "N"),
]


def test_a_revisit_just_outside_the_room_is_found_by_surface_alignment_within_the_search_radius():
    # 0.9 m of drift a transition (of 1-2.5 m): far more than odometry trusted to 5 cm a metre allows, so
    # the pose graph here is told to expect it (odometry_sigma_xy 0.5 m a metre).
    assert accepted(drive(GlobalMap(PAPER), RETURN, per_step=(0.9, 0.0, 0.0))) == []
    gm = GlobalMap(FULL.replace(odometry_sigma_xy=0.5))
    events = drive(gm, RETURN, per_step=(0.9, 0.0, 0.0))
    assert accepted(events) == [(3, 1, "aligned-crosscheck")]
    a = gm.alignments[(3, 1)]
    assert a.correction[0] == pytest.approx(-1.8, abs=0.1) and a.constraint > 0.2


def test_an_aligned_revisit_the_drift_cannot_explain_is_refused():
    # The same revisit with the default odometry trust: moving ASR 3 by 1.8 m after two transitions
    # is many of the graph's standard deviations (near_drift_sigmas), so the alignment found a
    # neighbouring place of like shape, not the drift; with the gate off it is accepted.
    gm = GlobalMap(FULL)
    assert accepted(drive(gm, RETURN, per_step=(0.9, 0.0, 0.0))) == []
    assert gm.alignments[(3, 1)] is not None
    off = GlobalMap(FULL.replace(near_drift_sigmas=0.0))
    assert accepted(drive(off, RETURN, per_step=(0.9, 0.0, 0.0))) == [(3, 1, "aligned-crosscheck")]


def test_an_earlier_asr_checked_again_is_not_matched_by_alignment_alone_onto_a_later_one():
    # RETURN with the search radius off while driving: 3 stays unmatched. Checked again (re-entered
    # and grown, say), room 1 has the later 3 only within the search radius: that pair is 3 -> 1
    # tried the other way round (near_earlier_only), so only 3's own check may close it so.
    def driven(**changes):
        gm = GlobalMap(FULL.replace(odometry_sigma_xy=0.5, search_radius=0.0))
        assert accepted(drive(gm, RETURN, per_step=(0.9, 0.0, 0.0))) == []
        gm.params = gm.params.replace(search_radius=2.0, **changes)
        return gm

    gm = driven()
    assert accepted(gm.check(1, 4.0)) == []
    assert accepted(gm.check(3, 4.0)) == [(3, 1, "aligned-crosscheck")]
    assert accepted(driven(near_earlier_only=False).check(1, 4.0)) == [(1, 3, "aligned-crosscheck")]


def test_a_corridor_just_outside_is_not_matched_by_alignment_alone():
    # Two straight corridor pieces: the alignment along them is unobserved, so no match.
    route = [
        ((0, 0, 8, 2), (1.0, 1.0, 0.0), "EW"),
        ((8, 0, 10, 12), (9.0, 1.0, math.pi / 2), "SN"),
        ((0, 0, 8, 2), (7.0, 1.0, math.pi), "EW"),
    ]
    events = drive(GlobalMap(FULL), route, per_step=(0.0, 1.1, 0.0))
    assert accepted(events) == []


# A straight corridor walked east in three 8 m pieces; odometry loses 7 m per piece, so the third
# piece (truly 16-24 m) is placed on the first (0-8 m): both centres lie deep inside each other's
# polygon, yet the two never overlap. Their walls all run east-west: no alignment can tell.
STRAIGHT = [
    ((0, 0, 8, 2), (1.0, 1.0, 0.0), "EW"),
    ((8, 0, 16, 2), (9.0, 1.0, 0.0), "EW"),
    ((16, 0, 24, 2), (17.0, 1.0, 0.0), "EW"),
]


def test_a_straight_corridor_aliased_by_drift_along_it_is_not_closed_in_extended_mode():
    drift_along = (-7.0, 0.0, 0.0)
    # The paper's check cannot tell: it accepts the false closure ...
    assert accepted(drive(GlobalMap(PAPER), STRAIGHT, per_step=drift_along)) == [(3, 1, "centre-crosscheck")]
    # ... and so did verification while it asked the alignment for a low residual only.
    loose = FULL.replace(verify_constrained=0.0)
    assert accepted(drive(GlobalMap(loose), STRAIGHT, per_step=drift_along)) == [(3, 1, "centre-crosscheck")]
    # The drift bound takes the pose graph's word, which here is odometry's: 1 m of travel believed
    # between the pieces' frames, so 7 m of drift is beyond any bound it would set (a localiser
    # sliding along a featureless corridor could do this; odometry cannot). Without it:
    gm = GlobalMap(FULL.replace(drift_bound_sigmas=0.0))
    events = drive(gm, STRAIGHT, per_step=drift_along)
    assert accepted(events) == []
    assert [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)] == [
        (3, 1, "verification")
    ]
    assert gm.alignments[(3, 1)].constraint < 0.01


def test_a_straight_corridor_piece_failing_the_crosscheck_is_not_aligned_onto_it():
    # 6 m of drift along the corridor a piece: the third piece's centre lies in the first, the
    # first's not in the third by the margin; along the walls no alignment can say more.
    gm = GlobalMap(FULL)
    events = drive(gm, STRAIGHT, per_step=(-6.0, 0.0, 0.0))
    assert accepted(events) == []
    assert [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)] == [
        (3, 1, "centre-crosscheck")
    ]
    assert gm.alignments[(3, 1)].constraint < 0.01


def test_a_straight_pieces_alignment_keeps_the_dead_reckoned_place_along_its_open_axis():
    # Surfaces all along a corridor running at 30 deg: ICP's slide along it is not measured, so it
    # is taken back; its move across the corridor and its rotation stay.
    axis = math.radians(30.0)
    u, n = np.array([math.cos(axis), math.sin(axis)]), np.array([-math.sin(axis), math.cos(axis)])
    pts = np.array([[4.0, 1.0], [6.0, 2.2], [5.0, 3.1], [7.5, 3.0]])
    slide = (*(1.7 * u + 0.12 * n), 0.0)  # 1.7 m along (the ICP slide), 0.12 m across
    spin = (0.0, 0.0, 0.02)  # about the global origin
    a = Alignment(compose(slide, spin), 0.01, 0.9, 1.7, constraint=0.0, axis=axis)
    b = _unslid(a, pts)
    move = transform_points(b.correction, pts).mean(axis=0) - pts.mean(axis=0)
    spun = transform_points(spin, pts).mean(axis=0) - pts.mean(axis=0)
    assert float(move @ u) == pytest.approx(0.0, abs=1e-12)
    assert float(move @ n) == pytest.approx(0.12 + float(spun @ n), abs=1e-12)
    assert b.correction[2] == pytest.approx(0.02) and b.shift == pytest.approx(float(np.hypot(*move)))
    assert (b.constraint, b.axis, b.rms, b.inliers) == (a.constraint, a.axis, a.rms, a.inliers)


def test_a_loop_edge_carries_information_only_along_the_axes_its_alignment_observed():
    from mapper.cycles import Alignment

    gm = GlobalMap(FULL)
    full, loose = 1 / FULL.loop_sigma_xy**2, 1 / FULL.loop_sigma_unverified_xy**2
    # A corridor running along global x, the duplicate's frame facing global +y: the unobserved
    # axis is the frame's y axis (the error of a loop edge is expressed in the duplicate's frame).
    corridor = Alignment((0.0, 0.0, 0.0), 0.02, 0.9, 0.0, constraint=0.0, axis=0.0)
    info = gm._loop_info(corridor, math.pi / 2)
    assert info[0, 0] == pytest.approx(full) and info[1, 1] == pytest.approx(loose)
    assert info[0, 1] == pytest.approx(0.0, abs=1e-9)
    assert info[2, 2] == pytest.approx(1 / FULL.loop_sigma_theta**2)
    room = Alignment((0.0, 0.0, 0.0), 0.02, 0.9, 0.0, constraint=0.45, axis=0.7)
    assert np.allclose(gm._loop_info(room, 0.3)[:2, :2], full * np.eye(2))
    # An axis half as constrained as loop_constraint_full gets half the information.
    half = Alignment((0.0, 0.0, 0.0), 0.02, 0.9, 0.0, constraint=FULL.loop_constraint_full / 2, axis=0.0)
    assert gm._loop_info(half, 0.0)[0, 0] == pytest.approx(full / 2)


def _closed_pair(params):
    """A mapper whose ASR 2 (being grown) is an accepted duplicate of ASR 1, a 4 m x 4 m room."""
    import shapely

    from mapper.asr_builder import AsrBuilder
    from mapper.mapper import Mapper
    from mapper.params import MapperParams

    m = Mapper(MapperParams(cycles=params))
    room = box_asr(1, (0, 0, 4, 4), (0.0, 0.0, 0.0))
    m._gm.add_first(room)
    m._asrs[1] = room
    b = AsrBuilder(2, 2.0, (0.0, 0.0, 0.0), m.params)
    before = shapely.box(0.5, 0.0, 4.0, 4.0)
    b.polygon, b.stale = before, True
    b.ensure_labels()
    m._asrs[2] = m._gm.asrs[2] = b.asr
    b.asr.duplicate_of = 1
    m._gm._pair(2, 1)
    return m, b, before


def test_a_view_that_would_move_a_duplicates_centre_out_of_its_match_is_not_unioned():
    import shapely

    m, b, before = _closed_pair(FULL)
    assert m._gm.closure_depth(2) > FULL.crosscheck_margin
    b.polygon = shapely.box(0.5, 0.0, 9.0, 4.0)  # its centre (4.75, 2) would lie outside the room
    assert m._gm.closure_depth(2, b.polygon) < 0
    m._hold_closures(b, before, (2.0, 2.0, 0.0))
    assert b.polygon.area == pytest.approx(before.area, rel=1e-6)
    b.polygon = shapely.box(0.5, 0.0, 5.0, 4.0)  # centre (2.75, 2): still 1.25 m inside: kept
    m._hold_closures(b, before, (2.0, 2.0, 0.0))
    assert b.polygon.area == pytest.approx(18.0)
    # The paper's plain method lets the duplicate grow as it will.
    m, b, before = _closed_pair(PAPER)
    b.polygon = shapely.box(0.5, 0.0, 9.0, 4.0)
    m._hold_closures(b, before, (2.0, 2.0, 0.0))
    assert b.polygon.area == pytest.approx(34.0)


@pytest.mark.parametrize(("margin", "verified"), [(0.1, True), (0.3, False)])
def test_a_verified_alignment_needs_the_centres_only_verify_crosscheck_margin_deep(margin, verified):
    # Two 4 m rooms' worth of one space, overlapping 2.2 m: once aligned, each centre lies 0.2 m
    # inside the other polygon. The unaligned crosscheck (with drift) asked for crosscheck_margin;
    # with the walls aligned, verify_crosscheck_margin is asked (default 0.3 m, as crosscheck_margin).
    params = FULL.replace(verify_crosscheck_margin=margin)
    gm = GlobalMap(params)
    a, b = box_asr(1, (0, 0, 4, 4), (0.0, 0.0, 0.0), "E"), box_asr(2, (1.8, 0, 5.8, 4), (0.0, 0.0, 0.0), "W")
    gm.asrs[1], gm.asrs[2] = a, b
    good = Alignment(correction=(0.0, 0.0, 0.0), rms=0.02, inliers=0.9, shift=0.0, constraint=0.3)
    assert gm._verified(good, 2, 1) is verified
    assert gm._verified(dataclasses.replace(good, correction=(0.15, 0.0, 0.0)), 2, 1) is False  # 0.05 m deep
    # A candidate found only by the search radius had no unaligned crosscheck: crosscheck_margin.
    assert gm._verified(good, 2, 1, near=True) is False


def test_a_crosschecked_revisit_of_a_cluttered_room_may_see_clutter_in_the_others_free_space():
    # One room, twice: each centre lies 1 m inside the other by dead reckoning (the unaligned
    # crosscheck passed). The alignment is good but 10 % of the surface points (chair legs, table
    # edges one view saw and the other's simplified polygon cuts across) lie in the other's free
    # space: allowed after the crosscheck with half the surfaces agreeing, not otherwise.
    gm = GlobalMap(FULL)
    gm.asrs[1] = box_asr(1, (0, 0, 6, 5), (0.0, 0.0, 0.0), "E")
    gm.asrs[2] = box_asr(2, (1, 0, 7, 5), (0.0, 0.0, 0.0), "W")
    cluttered = Alignment(correction=(0.0, 0.0, 0.0), rms=0.03, inliers=0.6, shift=0.0, constraint=0.3,
                          violation=0.1)
    assert gm._verified(cluttered, 2, 1) is True
    assert gm._verified(dataclasses.replace(cluttered, violation=0.25), 2, 1) is False
    # A poor fit (CSAIL corrected's false matches: 41-43 % inliers) keeps the strict limit, ...
    assert gm._verified(dataclasses.replace(cluttered, inliers=0.45), 2, 1) is False
    assert gm._verified(dataclasses.replace(cluttered, inliers=0.45, violation=0.04), 2, 1) is True
    # ... as does an alignment its surfaces leave open along one axis (a corridor piece that may
    # have slid onto its neighbour, seeing its end in the other's free space), placed by its exits
    # and matched by both its walls, 2 m apart ...
    corridor = dataclasses.replace(cluttered, constraint=0.0, pinned=0.1, across=2.0)
    assert gm._verified(dataclasses.replace(corridor, violation=0.04), 2, 1) is True
    assert gm._verified(corridor, 2, 1) is False
    # ... as does a candidate with no unaligned crosscheck behind it, and one re-examined in hindsight.
    assert gm._verified(cluttered, 2, 1, near=True) is False
    assert gm._verified(cluttered, 2, 1, margin=0.1) is False
    gm.params = FULL.replace(verify_crosschecked_violation=FULL.verify_max_violation)
    assert gm._verified(cluttered, 2, 1) is False


def _room_and_next():
    """ASR 1, a 4 m x 3 m room with an exit on its east side; ASR 2 beyond it, entered through it."""
    gm = GlobalMap(FULL)
    room = box_asr(1, (0, 0, 4, 3), (0.0, 0.0, 0.0), "E")
    gm.add_first(room)
    beyond = box_asr(2, (4, 0, 8, 3), (4.1, 1.5, 0.0), "W")
    gm.add_created(beyond, 1, "1/0", "2/0", (4.1, 1.5, 0.0), 1.0)
    return gm, room


def test_a_doorway_whose_exit_was_renamed_leads_where_it_led_before():
    gm, room = _room_and_next()
    old = room.exits[0]
    room.exits = [Exit("1/3", old.a, old.b)]  # a relabelling dropped 1/0; the doorway is 1/3 now
    assert gm.lookup(1, "1/3") is None
    tr = gm.relink(1, "1/3", (4.0, 1.2), 0.6, among={1, 2})
    assert (tr.exit, tr.dst, tr.via) == ("1/3", 2, "2/0")
    assert gm.lookup(1, "1/3") == tr and gm.lookup(1, "1/0") is None
    assert room.exits[0].to == 2
    assert gm.lookup(2, "2/0").via == "1/3"
    assert [(ln.src, ln.exit, ln.dst, ln.via) for ln in gm.topology.links] == [(1, "1/3", 2, "2/0")]


def test_a_new_exit_elsewhere_or_beside_a_live_one_is_not_relinked():
    gm, room = _room_and_next()
    assert gm.relink(1, "1/3", (4.0, 1.2), 0.6, among={1}) is None  # 2 cannot be re-entered
    assert gm.relink(1, "1/3", (4.0, 1.2), 0.6, among={1, 2}) is None  # 1/0 is still there
    room.exits = [Exit("1/3", (0.0, 2.0), (0.0, 1.0))]  # 1/0 gone, and a doorway on the west side
    assert gm.relink(1, "1/3", (0.0, 1.5), 0.6, among={1, 2}) is None
    assert gm.lookup(1, "1/0").dst == 2


def test_a_straight_piece_revisited_before_the_corner_is_closed_in_hindsight_by_the_topology():
    # Round the block from the west side: the west piece is met again (5 onto 1) before the corner
    # (6 onto 2). 5's walls all run north-south, so its match waits; once 6 closes onto the corner,
    # 5 lies beside the same place as 1 does, and hindsight accepts it (topological_anchor).
    # (The pieces' ends are exits, which would pin 5 at once: exit_pin_sigmas is off here.)
    route = [LOOP[3], LOOP[0], LOOP[1], LOOP[2], LOOP[3], LOOP[0]]
    unpinned = FULL.replace(exit_pin_sigmas=0.0)
    events = drive(GlobalMap(unpinned), route, per_step=(0.15, -0.1, 0.02))
    got = accepted(events)
    assert (6, 2, "centre-crosscheck") in got and (5, 1, "hindsight") in got, got
    rejected = [(e.asr, e.matches, e.reason) for e in events if isinstance(e, CycleRejected)]
    assert (5, 1, "verification") in rejected
    # Without the anchor, the pose graph bounds the drift once 6 -> 2 closed the loop: hindsight
    # accepts 5 -> 1 all the same (drift_bound_sigmas). Without either the piece stays unclosed.
    events = drive(GlobalMap(unpinned.replace(topological_anchor=False)), route, per_step=(0.15, -0.1, 0.02))
    assert accepted(events) == [(6, 2, "centre-crosscheck"), (5, 1, "hindsight")]
    events = drive(GlobalMap(unpinned.replace(topological_anchor=False, drift_bound_sigmas=0.0)), route,
                   per_step=(0.15, -0.1, 0.02))
    assert accepted(events) == [(6, 2, "centre-crosscheck")]


def test_a_straight_piece_is_closed_by_the_drift_bound_only_while_the_pose_graph_bounds_the_drift():
    # LOOP's 6 onto 2 is a straight piece (walls east and west): with the anchor off, the pose graph
    # decides. With odometry trusted to 5 cm a metre, 6 lies within 2 by far more than twice its
    # standard deviation along the piece; with 0.6 m a metre (a graph that cannot bound the drift)
    # the same match is refused, as verify_constrained alone refuses it.
    unanchored = FULL.replace(topological_anchor=False, exit_pin_sigmas=0.0)
    gm = GlobalMap(unanchored)
    assert (6, 2, "centre-crosscheck") in accepted(drive(gm, LOOP, per_step=(0.15, -0.1, 0.02)))
    assert gm.alignments[(6, 2)].constraint < 0.01
    loose = GlobalMap(unanchored.replace(odometry_sigma_xy=0.6))
    events = drive(loose, LOOP, per_step=(0.15, -0.1, 0.02))
    assert accepted(events) == [(5, 1, "centre-crosscheck")]
    assert any(isinstance(e, CycleRejected) and (e.asr, e.matches, e.reason) == (6, 2, "verification")
               for e in events)


def test_a_straight_piece_seen_by_one_wall_is_not_closed():
    # LOOP's 6 onto 2 again, but 6 has seen only the piece's outer (east) wall, its other sides
    # unexplored. One wall matches any wall facing the same way (verify_min_across): the anchor,
    # the drift bound and the exits that place a two-walled piece cannot place this one. With the
    # rule off it is closed as before.
    route = [*LOOP[:5], (LOOP[5][0], LOOP[5][1], "SNW")]
    gm = GlobalMap(FULL)
    events = drive(gm, route, per_step=(0.15, -0.1, 0.02))
    assert accepted(events) == [(5, 1, "centre-crosscheck")]
    assert gm.alignments[(6, 2)].across < 0.01 and gm.alignments[(6, 2)].inliers == 1.0
    assert any(isinstance(e, CycleRejected) and (e.asr, e.matches, e.reason) == (6, 2, "verification")
               for e in events)
    events = drive(GlobalMap(FULL.replace(verify_min_across=0.0)), route, per_step=(0.15, -0.1, 0.02))
    assert accepted(events) == [(5, 1, "centre-crosscheck"), (6, 2, "centre-crosscheck")]


def test_a_straight_piece_is_placed_along_its_length_by_its_exits():
    # The same route with only the exits to say where along the west piece 5 lies: its walls run
    # north-south, its ends are exits (the corridor going on round the corners). Aligned by the
    # walls alone it stays where 4 transitions of drift put it; the ends move it onto 1's, and the
    # match is accepted at once, placed where 5 truly is.
    route = [LOOP[3], LOOP[0], LOOP[1], LOOP[2], LOOP[3], LOOP[0]]
    per_step = (0.15, -0.1, 0.02)
    gm = GlobalMap(FULL.replace(topological_anchor=False, drift_bound_sigmas=0.0))
    events = drive(gm, route, per_step=per_step)
    assert accepted(events) == [(5, 1, "centre-crosscheck"), (6, 2, "centre-crosscheck")]
    a = gm.alignments[(5, 1)]
    assert a.constraint < 0.01 and a.pinned is not None
    believed = compose(drift(4, per_step), route[4][1])
    placed = compose(a.correction, believed)
    unpin = (-a.pinned * math.cos(a.axis), -a.pinned * math.sin(a.axis), 0.0)
    walls_only = compose(compose(unpin, a.correction), believed)
    truth = route[4][1]
    assert math.dist(placed[:2], truth[:2]) < 0.1
    assert math.dist(walls_only[:2], truth[:2]) > 0.3


def _door(x0: float, y: float = 0.0, width: float = 0.9) -> list:
    return [[x0, y], [x0 + width, y]]


def test_exits_pin_an_open_axis_only_when_one_shift_within_the_reach_explains_them():
    axis = 0.0  # the open axis runs along x (a corridor along x, doorways in its south wall)
    p = np.array([_door(0.3)])
    q = np.array([_door(0.0), _door(4.0)])
    assert exit_pin(p, q, axis, 0.2, 1.0) == pytest.approx((-0.3, 1))  # the door 4 m on is out of reach
    assert exit_pin(p, q, axis, 0.2, 4.0) is None  # within reach of both doors: which one?
    assert exit_pin(p, np.array([_door(0.0, y=0.5)]), axis, 0.2, 1.0) is None  # across the axis: not the same
    assert exit_pin(p, np.array([_door(0.0, width=1.5)]), axis, 0.2, 1.0) is None  # another width
    assert exit_pin(p, np.array([[[0.75, -0.45], [0.75, 0.45]]]), axis, 0.2, 1.0) is None  # crosswise
    two = np.array([_door(0.3), _door(4.3)])
    assert exit_pin(two, q, axis, 0.2, 1.0) == pytest.approx((-0.3, 2))  # both doors agree
    assert exit_pin(p, np.zeros((0, 2, 2)), axis, 0.2, 1.0) is None


def test_an_aligned_match_is_refused_when_it_brings_the_asr_entered_from_into_the_match():
    # verify_parent: room 1 (3 m x 4 m, open north) is the candidate; 3 was entered from 2, the
    # corridor north of the rooms (open south). The alignment's correction, applied to 2 too:
    # unmoved, or along the corridor, 2 stays out of 1's free space and 1 out of 2's; moved 2 m
    # south, 2's north wall runs through room 1, so 3 is not 1 (a like room next door).
    gm = GlobalMap(FULL)
    room = box_asr(1, (0, 0, 3, 4), (1.5, 2.0, 0.0), "N")
    corridor = box_asr(2, (0, 4, 7, 6), (3.5, 5.0, 0.0), "S")
    other = box_asr(3, (4, 0, 7, 4), (5.5, 2.0, 0.0), "N")
    for a, frame in ((room, (1.5, 2.0, 0.0)), (corridor, (3.5, 5.0, 0.0)), (other, (5.5, 2.0, 0.0))):
        a.origin = frame
        gm.asrs[a.id] = a
    gm._came_from[3] = 2

    def along(correction):
        return Alignment(correction=correction, rms=0.01, inliers=1.0, shift=0.0)

    assert gm._parent_agrees(along((0.0, 0.0, 0.0)), 3, 1)
    assert gm._parent_agrees(along((-4.0, 0.0, 0.0)), 3, 1)
    assert not gm._parent_agrees(along((0.0, -2.0, 0.0)), 3, 1)
    assert GlobalMap(FULL.replace(verify_parent=False))._parent_agrees(along((0.0, -2.0, 0.0)), 3, 1)
    gm._came_from[3] = None  # entered from nothing: nothing to check
    assert gm._parent_agrees(along((0.0, -2.0, 0.0)), 3, 1)
