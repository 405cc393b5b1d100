"""Localisation inside ASRs on the real MIT CSAIL run: corrected poses beat raw odometry.

Raw scans and odometry: mit-csail.clf.gz. Truth: the SLAM-corrected robot poses of
csail-robotlaser1.log.gz, whose ipc timestamps equal the raw log's (SOURCES.md). The relative pose
error (RPE) compares the motion between two truth poses d metres of travel apart with the motion
between the same two scans' estimates, so the global frame and the drift before i do not matter.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from raycast import box, cast

from mapper.lines import scan_points
from mapper.localise import Localiser
from mapper.mapper import Mapper
from mapper.params import MapperParams
from mapper.se2 import between
from mapper.types import Odometry
from service.carmen import CarmenReader, LaserRecord, mapper_inputs

LOG_PARAMS = MapperParams(laser_x=0.0, laser_y=0.0)


def rpe(est, truth, d: float) -> float:
    """Mean translational relative pose error (m) over pairs d metres of true travel apart."""
    g = np.asarray(truth)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(g[:, :2], axis=0).T))])
    errs = []
    for i in range(len(g)):
        j = int(np.searchsorted(cum, cum[i] + d))
        if j >= len(g):
            break
        a, b = between(est[i], est[j]), between(tuple(g[i]), tuple(g[j]))
        errs.append(math.hypot(a[0] - b[0], a[1] - b[1]))
    return float(np.mean(errs))


@pytest.fixture(scope="module")
def csail_run(shared_data):
    m = Mapper(LOG_PARAMS)
    log, truth = shared_data / "mit-csail.clf.gz", shared_data / "csail-robotlaser1.log.gz"
    est, raw, gt = run_against_truth(m, log, truth, 6)
    return est, raw, gt, m


def run_against_truth(m: Mapper, log, truth_log, digits: int):
    """Feed ``log`` to ``m``; at the scans the truth log also has (timestamps equal to ``digits``
    decimals): the mapper's global poses, the raw odometry poses and the true poses."""
    truth = {round(r.t, digits): r.pose for r in CarmenReader(truth_log) if isinstance(r, LaserRecord)}
    est, raw, gt, odo = [], [], [], None
    for item in mapper_inputs(log):
        if isinstance(item, Odometry):
            m.add_odometry(item)
            odo = item.pose
            continue
        m.add_scan(item)
        k = round(item.t, digits)
        if k in truth:
            est.append(m.global_pose)
            raw.append(odo)
            gt.append(truth[k])
    return est, raw, gt


def test_truth_matches_686_raw_scans(csail_run):
    _, _, gt, _ = csail_run
    assert len(gt) == 686


@pytest.mark.parametrize("d", [1.0, 5.0])
def test_correction_lowers_relative_pose_error(csail_run, d):
    est, raw, gt, m = csail_run
    e_raw, e_cor = rpe(raw, gt, d), rpe(est, gt, d)
    print(f"RPE over {d:.0f} m: raw odometry {e_raw:.3f} m, corrected {e_cor:.3f} m ({len(m.asrs)} ASRs)")
    assert e_cor < e_raw


def test_histogram_match_recovers_a_known_offset():
    # reference scan at the origin of an L-shaped room; the robot really stands at (0.12, -0.08, 3°)
    # but odometry says (0, 0, 0): the match must pull the estimate most of the way to the truth
    walls = [*box(-2, -1.5, 3, 2.5), ((1.0, 2.5), (1.0, 1.2)), ((1.0, 1.2), (3.0, 1.2))]
    p = MapperParams(laser_x=0.0, laser_y=0.0)
    loc = Localiser(p)
    loc.add_reference(scan_points(cast(walls, (0, 0, 0)), p).xy, (0.0, 0.0, 0.0))
    true = (0.12, -0.08, math.radians(3.0))
    loc.kf.P = np.diag([0.1**2, 0.1**2, math.radians(5) ** 2])  # an uncertain prediction
    match = loc.correct(scan_points(cast(walls, true), p).xy)
    assert match is not None and match.accepted, match
    err = between(true, loc.pose)
    # from 0.144 m and 3° off to within one 5 cm histogram bin and a degree
    assert math.hypot(err[0], err[1]) < 0.05 and abs(err[2]) < math.radians(1.0)


def test_a_restored_reference_matches_exactly_as_the_rebuilt_one():
    """Re-entering an ASR restores the reference the robot left it with instead of rebuilding it."""
    p = MapperParams(laser_x=0.0, laser_y=0.0)
    walls = box(0.0, 0.0, 6.0, 4.0)
    views = [(1.0 + 0.3 * k, 2.0, 0.1 * k) for k in range(7)]
    refs = [(scan_points(cast(walls, v, n=181, max_range=30.0), p).xy, (v[0] - 1.0, v[1] - 2.0, v[2]))
            for v in views]
    here = scan_points(cast(walls, (2.1, 2.05, 0.33), n=181, max_range=30.0), p).xy
    rebuilt, restored = Localiser(p), Localiser(p)
    rebuilt.reset((1.05, 0.0, 0.3))
    rebuilt.add_references(refs)
    for xy, at in refs:
        restored.add_reference(xy, at)
    kept = restored.reference()
    restored.reset((1.05, 0.0, 0.3))
    restored.restore_reference(kept)
    a, b = rebuilt.correct(here), restored.correct(here)
    assert a is not None and a == b
    assert np.array_equal(rebuilt.kf.x, restored.kf.x) and np.array_equal(rebuilt.kf.P, restored.kf.P)


def test_along_a_featureless_corridor_the_match_leaves_the_along_axis_to_odometry():
    # Two parallel walls, 16 m long, 1.6 m apart. The reference is seen from x = 0, the robot stands
    # at x = 0.3 and odometry says so too: the walls say nothing about x, and the correlation along
    # them is flat, so the match must not pull x back towards the reference (it used to, by the
    # extent of the two point sets), while it still measures y.
    walls = [((-8.0, -0.8), (8.0, -0.8)), ((-8.0, 0.8), (8.0, 0.8))]
    p = MapperParams(laser_x=0.0, laser_y=0.0)
    loc = Localiser(p)
    loc.add_reference(scan_points(cast(walls, (0, 0, 0)), p).xy, (0.0, 0.0, 0.0))
    loc.kf.x = np.array([0.3, 0.05, 0.0])  # odometry: right along x, 5 cm off in y
    loc.kf.P = np.diag([0.1**2, 0.1**2, math.radians(2) ** 2])
    match = loc.correct(scan_points(cast(walls, (0.3, 0.0, 0.0)), p).xy)
    assert match is not None and match.accepted, match
    assert match.q_u < p.min_quality or match.q_v < p.min_quality  # the along axis: not measured
    assert loc.pose[0] == pytest.approx(0.3, abs=0.03)
    assert abs(loc.pose[1]) < 0.03


@pytest.mark.slow
def test_viewpoint_refinement_lowers_the_intel_drift(shared_data):
    """Intel raw's odometry turns ~0.65°/s too little; the histogram matches alone let each ASR drift
    about 2° (README, "Cycle closing"). Refining the viewpoints must lower the error over 20 m."""
    log, truth = shared_data / "intel-raw-first5505.clf.gz", shared_data / "intel-corrected.log.gz"
    off = dataclasses.replace(LOG_PARAMS, cycles=dataclasses.replace(LOG_PARAMS.cycles, enabled=False))
    est, _, gt = run_against_truth(Mapper(off), log, truth, 3)
    plain, _, _ = run_against_truth(Mapper(dataclasses.replace(off, refine=False)), log, truth, 3)
    for d in (1.0, 5.0, 20.0):
        print(f"Intel raw RPE over {d:.0f} m: refined {rpe(est, gt, d):.3f} m, histogram only "
              f"{rpe(plain, gt, d):.3f} m ({len(gt)} truth scans)")
    assert rpe(est, gt, 20.0) < rpe(plain, gt, 20.0)
