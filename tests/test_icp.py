"""mapper.icp: the hashed grid finds the kd-tree's nearest points; the compiled ICP recovers a motion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapper.icp import PointGrid, grid_nearest, icp
from mapper.jit import kernel
from mapper.nearest import point_tree


@kernel
def _nearest_all(q: np.ndarray, bound: float, cell: float, grid) -> np.ndarray:
    out = np.empty(q.shape[0], np.int64)
    for i in range(q.shape[0]):
        out[i], _ = grid_nearest(q[i, 0], q[i, 1], bound, cell, grid)
    return out


def _walls(spacing: float = 0.02) -> np.ndarray:
    """Points 2 cm apart along an L of walls and a pillar (m), like a densified reference."""
    t = np.arange(0.0, 12.0, spacing)
    u = np.arange(0.0, 5.0, spacing)
    a = np.linspace(0.0, 2 * math.pi, 60, endpoint=False)
    return np.concatenate([
        np.c_[t - 6.0, np.full_like(t, -1.5)],
        np.c_[np.full_like(u, 6.0), u - 1.5],
        np.c_[1.0 + 0.2 * np.cos(a), 1.0 + 0.2 * np.sin(a)],
    ])


@pytest.mark.parametrize("cell", [0.05, 0.15, 0.4])
def test_the_grid_finds_the_kd_trees_nearest_point_within_the_bound(cell):
    rng = np.random.default_rng(7)
    differ = total = found = 0
    for trial in range(60):
        if trial % 2:
            ref = rng.uniform(-30.0, 30.0, (int(rng.integers(1, 2500)), 2)) * rng.uniform(0.01, 1.0)
        else:
            ref = _walls() + rng.normal(0.0, 0.005, (len(_walls()), 2))
        q = ref[rng.integers(0, len(ref), 250)] + rng.normal(0.0, rng.uniform(0.01, 2.0), (250, 2))
        q[:5] = (-1e3, 1e3)  # far outside every cell
        for bound in (0.08, 0.3, 3.0):
            got = _nearest_all(q, bound, cell, PointGrid(ref, cell).arrays)
            _, want = point_tree(ref).query(q, distance_upper_bound=bound)
            want = np.where(want == len(ref), -1, want.astype(np.int64))
            differ += int(np.count_nonzero(got != want))
            total += len(q)
            found += int(np.count_nonzero(want >= 0))
    assert total == 45_000 and 0 < found < total  # some queries have a neighbour, some none
    assert differ == 0


def test_an_empty_grid_finds_nothing():
    grid = PointGrid(np.empty((0, 2)), 0.15)
    assert list(_nearest_all(np.zeros((3, 2)), 1.0, 0.15, grid.arrays)) == [-1, -1, -1]


def test_icp_recovers_a_small_motion_and_reports_its_inliers():
    ref = _walls()
    grid = PointGrid(ref, 0.15)
    truth = (0.4, -0.2, math.radians(3.0))  # the scan's pose in the reference frame
    c, s = math.cos(truth[2]), math.sin(truth[2])
    world = ref[::3]
    # the scan: the same wall points, seen from `truth` (robot frame)
    d = world - np.array(truth[:2])
    xy = np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]]
    gates = np.geomspace(0.30, 0.08, 12)
    n, x, y, th, cur, j = icp(xy, ref, 0.43, -0.17, math.radians(2.0), gates, 0.08, grid.cell,
                              grid.arrays)
    assert n == len(xy)
    # from 3 cm, 3 cm and 1° off (a histogram match's error) to within 1 cm and 0.1°: paired with
    # discrete points 2 cm apart, ICP settles 0.08° off
    assert (x, y) == pytest.approx(truth[:2], abs=1e-2)
    assert th == pytest.approx(truth[2], abs=math.radians(0.1))
    assert np.all(j >= 0)
    assert np.abs(cur - world).max() < 2e-2
    # far from the reference (10 m off), nothing pairs: fewer than 20 pairs, no motion made up
    n, x, y, th, _, _ = icp(xy, ref, 10.4, 9.8, 0.05, gates, 0.08, grid.cell, grid.arrays)
    assert n < 20 and (x, y, th) == (10.4, 9.8, 0.05)


def test_points_not_finite_are_left_out_of_the_grid_and_bad_poses_pair_with_nothing():
    ref = _walls()
    holey = ref.copy()
    holey[::7] = np.nan
    holey[3, 1] = np.inf
    grid = PointGrid(holey, 0.15)
    q = ref[::5] + np.array([0.0037, 0.0061])  # off the ties between points 2 cm apart
    got = _nearest_all(q, 0.3, 0.15, grid.arrays)
    assert np.all(np.isfinite(holey[got[got >= 0]]))  # never a point that was not finite
    _, want = point_tree(np.nan_to_num(holey, nan=1e6, posinf=1e6)).query(q, distance_upper_bound=0.3)
    assert np.array_equal(got, np.where(want == len(holey), -1, want.astype(np.int64)))
    gates = np.geomspace(0.30, 0.08, 12)
    xy = ref[::3] - np.array([0.4, -0.2])
    for pose in [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, math.nan)]:
        n, *_, j = icp(xy, ref, *pose, gates, 0.08, 0.15, PointGrid(ref, 0.15).arrays)
        assert n == 0 and np.all(j == -1)
    bad = xy.copy()
    bad[10] = (math.nan, 1.0)
    assert icp(bad, ref, 0.4, -0.2, 0.0, gates, 0.08, 0.15, PointGrid(ref, 0.15).arrays)[0] == 0
    empty = PointGrid(np.empty((0, 2)), 0.15)
    assert icp(xy, np.empty((0, 2)), 0.4, -0.2, 0.0, gates, 0.08, 0.15, empty.arrays)[0] == 0


def test_an_infinite_bound_finds_the_nearest_point_however_far():
    ref = _walls()
    grid = PointGrid(ref, 0.15)
    q = np.array([[500.0, -300.0], [-2e4, 7.0], [0.5, 0.5]])
    got = _nearest_all(q, math.inf, 0.15, grid.arrays)
    _, want = point_tree(ref).query(q)
    assert list(got) == list(want.astype(np.int64))
