"""Evaluation against ground truth: truth carried by odometry, overlap, precision, revisits, recall."""

import math

import pytest

from mapper.cycle_params import CycleParams
from mapper.document import document_of
from mapper.globalmap import GlobalMap
from mapper.se2 import between, compose
from mapper.types import Odometry, Scan
from service.evaluate import (
    Track,
    describe_false,
    evaluate,
    is_corrected,
    rebuild_corrected,
    true_outlines,
    true_pose,
)
from tests.synthetic_asrs import drift, drive
from tests.test_cycles import LOOP


def test_truth_between_samples_is_carried_by_the_odometry_increments():
    truth = Track([0.0, 10.0], [(5.0, 5.0, math.pi / 2), (0.0, 0.0, 0.0)])
    # Odometry in its own (rotated, shifted) frame: 1 m straight ahead per second.
    odo = Track([0.0, 4.0], [(100.0, 0.0, math.pi), (96.0, 0.0, math.pi)])
    assert true_pose(truth, odo, 2.0) == pytest.approx((5.0, 7.0, math.pi / 2))
    assert true_pose(truth, odo, 0.0) == pytest.approx((5.0, 5.0, math.pi / 2))


def _loop(params, per_step=(0.15, -0.1, 0.02)):
    gm = GlobalMap(params)
    drive(gm, LOOP, per_step=per_step)
    frames = [f for _, f, _ in LOOP]
    times = [float(k) for k in range(1, len(LOOP) + 1)]
    truth = Track(times, frames)
    believed = [compose(drift(k, per_step), f) if k else f for k, f in enumerate(frames)]
    entered = {k: gm.topology.entered_from(k) for k in gm.asrs}
    return gm, truth, Track(times, believed), entered


# Extended mode without verify_constrained: LOOP's ASR 2 is a straight piece it leaves unclosed.
@pytest.mark.parametrize("params", [CycleParams.paper(), CycleParams(verify_constrained=0.0)],
                         ids=["paper", "extended"])
def test_a_loop_scores_full_precision_and_recall(params):
    gm, truth, odo, entered = _loop(params)
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert (ev.cycles, ev.true_positives, ev.false_positives) == (2, 2, 0)
    assert ev.precision == 1.0
    assert (ev.revisits, ev.detected, ev.recall) == (2, 2, 1.0)
    assert ev.evaluated == ev.asrs == 6


def test_revisit_drift_is_how_far_the_dead_reckoned_frames_misplace_each_revisit():
    gm, truth, odo, entered = _loop(CycleParams.paper(), per_step=(0.0, 0.0, 0.0))
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert len(ev.revisit_drift) == ev.revisits == 2 and max(ev.revisit_drift) < 1e-9
    gm, truth, odo, entered = _loop(CycleParams.paper())
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert len(ev.revisit_drift) == 2 and min(ev.revisit_drift) > 0.1  # 0.15 m, 0.02 rad per ASR


def test_realignment_lowers_the_frame_error_and_without_it_nothing_changes():
    gm, truth, odo, entered = _loop(CycleParams())
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert ev.frame_error_after < 0.5 * ev.frame_error_before
    gm, truth, odo, entered = _loop(CycleParams.paper())
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert ev.frame_error_after == ev.frame_error_before > 0.1


def test_a_cycle_between_places_that_do_not_overlap_is_a_false_positive_named_with_its_centres_depths():
    gm, truth, odo, entered = _loop(CycleParams.paper())
    doc = document_of(gm)
    doc["cycles"].append(
        {"time": 6.5, "asr": 6, "matches": 3, "accepted": True, "iou": 0.1, "reason": "test"}
    )
    ev = evaluate(doc, truth, odo, entered)
    assert ev.false_pairs == ((6, 3),) and ev.precision == pytest.approx(2 / 3)
    # each true centre's depth inside the other ASR's true outline, negative outside
    ((i, j, a, b),) = ev.false_depths
    assert (i, j) == (6, 3)
    _, polys, centres = true_outlines(doc["asrs"], truth, odo)
    for depth, (k, other) in ((a, (6, 3)), (b, (3, 6))):
        inside = polys[other].covers(centres[k])
        assert (depth >= 0) == inside
        assert abs(depth) == pytest.approx(polys[other].exterior.distance(centres[k]), abs=1e-9)
    assert min(a, b) < 0  # a pair whose centres both lie inside the other would truly overlap
    assert describe_false(ev.false_depths) == f"6 -> 3 (centres {a:.2f} / {b:.2f} m inside)"


def test_no_cycles_means_no_recall():
    gm, truth, odo, entered = _loop(CycleParams(enabled=False))
    ev = evaluate(document_of(gm), truth, odo, entered)
    assert ev.cycles == 0 and math.isnan(ev.precision)
    assert (ev.revisits, ev.detected, ev.recall) == (2, 0, 0.0)


def _corrected_log(tmp_path):
    """Three scans; corrected poses C, raw increments: 1 m ahead, then a 90° left turn."""
    ranges = " ".join(["2.0"] * 180)
    c = [(10.0, 10.0, 0.5), (11.0, 10.6, 0.55), (11.1, 10.6, 2.1)]
    inc = [None, (1.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2)]
    lines = ["# corrected", "ODOM 0 0 0 0 0 0 0.1 pippo 0.1"]
    for k, ck in enumerate(c):
        t = float(k + 1)
        if k:
            o = compose(c[k - 1], inc[k])
            lines.append(f"ODOM {o[0]!r} {o[1]!r} {o[2]!r} 0 0 0 {t} pippo {t}")
        p = " ".join(repr(v) for v in ck)
        lines.append(f"FLASER 180 {ranges} {p} {p} {t} pippo {t}")
        lines.append(f"ODOM {p} 0 0 0 0 pippo 0")
    f = tmp_path / "tiny-corrected.log"
    f.write_text("\n".join(lines) + "\n")
    return f, c


def test_a_corrected_log_is_rebuilt_into_dead_reckoning_with_its_poses_as_truth(tmp_path):
    f, c = _corrected_log(tmp_path)
    assert is_corrected(f)
    inputs, truth = rebuild_corrected(f)
    odo = [i for i in inputs if isinstance(i, Odometry)]
    assert len(odo) == 3 and sum(isinstance(i, Scan) for i in inputs) == 3
    assert truth.poses == c
    assert between(odo[0].pose, odo[1].pose) == pytest.approx((1.0, 0.0, 0.0))
    assert between(odo[1].pose, odo[2].pose) == pytest.approx((0.0, 0.0, math.pi / 2))


def test_a_raw_log_is_not_taken_for_a_corrected_one(tmp_path):
    ranges = " ".join(["2.0"] * 180)
    f = tmp_path / "raw.clf"
    f.write_text("".join(f"FLASER 180 {ranges} {k}.0 0 0 {k}.0 0 0 {k}.5 host {k}.5\n" for k in range(5)))
    assert not is_corrected(f)


def test_each_transition_error_is_the_dead_reckoned_frame_against_the_true_one():
    gm, truth, odo, entered = _loop(CycleParams.paper(), per_step=(0.0, 0.0, 0.0))
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    assert len(ev.transition_errors) == 5  # six ASRs, each after the first entered from one
    assert max(max(abs(p), abs(h)) for _, p, h in ev.transition_errors) < 1e-9
    gm, truth, odo, entered = _loop(CycleParams.paper(), per_step=(0.15, -0.1, 0.02))
    ev = evaluate(document_of(gm), truth, odo, entered, gm.odometry_origin)
    # every crossing adds 0.02 rad of heading error, and the frames are metres apart
    assert [h for _, _, h in ev.transition_errors] == pytest.approx([0.02] * 5, abs=1e-9)
    assert all(d > 1.0 and p > 0.01 for d, p, _ in ev.transition_errors)
