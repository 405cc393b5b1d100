"""The ASR pose graph: Jacobians against finite differences, and a drifted loop relaxed."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapper.posegraph import Edge, diagonal_info, errors_and_jacobians, optimise, relative_covariance
from mapper.se2 import between, compose

pose = st.tuples(st.floats(-10, 10), st.floats(-10, 10), st.floats(-math.pi + 1e-3, math.pi - 1e-3))


@settings(max_examples=60, deadline=None)
@given(pose, pose, pose)
def test_jacobians_match_central_finite_differences(xi, xj, z):
    xi, xj, z = (np.array(p) for p in (xi, xj, z))
    _, a, b = errors_and_jacobians(xi, xj, z)
    h = 1e-6
    for x, jac, which in ((xi, a[0], 0), (xj, b[0], 1)):
        num = np.zeros((3, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = h
            args_p = [xi, xj]
            args_m = [xi, xj]
            args_p[which] = x + d
            args_m[which] = x - d
            ep, _, _ = errors_and_jacobians(args_p[0], args_p[1], z)
            em, _, _ = errors_and_jacobians(args_m[0], args_m[1], z)
            diff = ep[0] - em[0]
            diff[2] = (diff[2] + math.pi) % (2 * math.pi) - math.pi
            num[:, k] = diff / (2 * h)
        np.testing.assert_allclose(jac, num, atol=1e-5)


def test_error_is_zero_when_the_measurement_is_exact():
    xi, xj = (1.0, 2.0, 0.3), (4.0, -1.0, 2.9)
    e, _, _ = errors_and_jacobians(np.array(xi), np.array(xj), np.array(between(xi, xj)))
    np.testing.assert_allclose(e, 0.0, atol=1e-12)


def _square_loop(drift_per_step: float):
    """Eight ASRs around a 4 m square; odometry edges true, estimates with accumulated heading drift."""
    truth = [(0.0, 0.0, 0.0)]
    step = (2.0, 0.0, 0.0)
    for k in range(1, 8):
        turn = math.pi / 2 if k % 2 == 0 else 0.0
        truth.append(compose(truth[-1], (step[0], 0.0, 0.0)))
        if turn:
            truth[-1] = (truth[-1][0], truth[-1][1], truth[-1][2] + turn)
    est = [truth[0]]
    for k in range(1, 8):
        rel = between(truth[k - 1], truth[k])
        est.append(compose(est[-1], (rel[0], rel[1], rel[2] + drift_per_step)))
    return truth, est


def test_a_loop_closure_pulls_a_drifted_chain_back():
    truth, est = _square_loop(drift_per_step=0.06)
    odo = diagonal_info(0.05, 0.03)
    edges = [Edge(k - 1, k, between(est[k - 1], est[k]), odo) for k in range(1, 8)]
    # The loop edge: ASR 7 seen from ASR 0, as surface alignment measures it (the truth).
    edges.append(Edge(0, 7, between(truth[0], truth[7]), diagonal_info(0.02, 0.01)))
    poses = dict(enumerate(est))
    res = optimise(poses, edges, fixed=0)
    err_before = np.hypot(*np.subtract(est[7][:2], truth[7][:2]))
    err_after = np.hypot(*np.subtract(res.poses[7][:2], truth[7][:2]))
    assert res.chi2_after < 0.01 * res.chi2_before
    assert err_after < 0.1 * err_before
    assert res.poses[0] == poses[0]


def test_nodes_without_edges_and_the_fixed_node_do_not_move():
    poses = {1: (0.0, 0.0, 0.0), 2: (1.0, 0.0, 0.0), 9: (5.0, 5.0, 1.0)}
    edges = [Edge(1, 2, (2.0, 0.0, 0.0), diagonal_info(0.1, 0.1))]
    res = optimise(poses, edges)
    assert res.poses[9] == poses[9] and res.poses[1] == poses[1]
    np.testing.assert_allclose(res.poses[2], (2.0, 0.0, 0.0), atol=1e-9)


def test_relative_covariance_sums_a_chain_and_a_second_path_tightens_it():
    # Three nodes along x, heading 0, rotation pinned: j's covariance seen from i is the sum of the
    # two edges' translation covariances.
    pinned = 1e-6
    edges = [Edge(0, 1, (2.0, 0.0, 0.0), diagonal_info(0.1, pinned)),
             Edge(1, 2, (2.0, 0.0, 0.0), diagonal_info(0.2, pinned))]
    poses = {0: (0.0, 0.0, 0.0), 1: (2.0, 0.0, 0.0), 2: (4.0, 0.0, 0.0)}
    cov = relative_covariance(poses, edges, 0, 2)
    np.testing.assert_allclose(cov[:2, :2], np.diag([0.05, 0.05]), rtol=1e-4, atol=1e-9)
    # the same seen from 2: symmetric
    np.testing.assert_allclose(relative_covariance(poses, edges, 2, 0)[:2, :2], cov[:2, :2], rtol=1e-4)
    # a second, independent path of the same covariance between 0 and 2 halves it
    loop = [*edges, Edge(0, 2, (4.0, 0.0, 0.0), diagonal_info(math.sqrt(0.05), pinned))]
    np.testing.assert_allclose(relative_covariance(poses, loop, 0, 2)[:2, :2], np.diag([0.025, 0.025]),
                               rtol=1e-4, atol=1e-9)


def test_relative_covariance_carries_heading_uncertainty_into_the_lateral_position():
    # Frame 1 lies 5 m along x from frame 0 with 0.1 rad of heading uncertainty, translation exact:
    # its origin is certain, its heading is not; frame 2, 3 m further along frame 1's x axis (an
    # exact edge), is 0.3 m uncertain sideways (y) and not along x.
    exact = np.diag([1e8, 1e8, 1e8])
    edges = [Edge(0, 1, (5.0, 0.0, 0.0), np.diag([1e8, 1e8, 100.0])), Edge(1, 2, (3.0, 0.0, 0.0), exact)]
    poses = {0: (0.0, 0.0, 0.0), 1: (5.0, 0.0, 0.0), 2: (8.0, 0.0, 0.0)}
    cov1 = relative_covariance(poses, edges, 0, 1)
    assert cov1[0, 0] < 1e-6 and cov1[1, 1] < 1e-6
    np.testing.assert_allclose(math.sqrt(cov1[2, 2]), 0.1, rtol=1e-4)
    cov2 = relative_covariance(poses, edges, 0, 2)
    np.testing.assert_allclose(math.sqrt(cov2[1, 1]), 0.3, rtol=1e-4)
    assert cov2[0, 0] < 1e-6


def test_relative_covariance_is_none_for_unjoined_or_unknown_nodes():
    poses = {0: (0.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0), 5: (9.0, 9.0, 0.0), 6: (9.0, 8.0, 0.0)}
    edges = [Edge(0, 1, (1.0, 0.0, 0.0), diagonal_info(0.1, 0.1)),
             Edge(5, 6, (0.0, -1.0, 0.0), diagonal_info(0.1, 0.1))]
    assert relative_covariance(poses, edges, 0, 5) is None
    assert relative_covariance(poses, edges, 0, 7) is None
    assert relative_covariance(poses, edges, 1, 1) is None
    assert relative_covariance(poses, edges, 0, 1) is not None
