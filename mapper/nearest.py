"""Nearest-neighbour queries over 2-D points (metres, any one frame): a kd-tree for the cycle
check's surface alignment (:func:`mapper.cycles.align_points`, which needs the 4 nearest).

:func:`point_tree` builds pykdtree's kd-tree. Against scipy's ``cKDTree`` (what the mapper used before)
it returns the same neighbours and is faster at the mapper's sizes: on the 939 viewpoint
refinements of the Intel raw log (about 2,100 reference points, 178 scan points) a query took
34 µs instead of 73 µs and a build 0.18 ms instead of 0.50 ms (one thread each). The viewpoint
refinement has since moved to :mod:`mapper.icp`, whose compiled loop cannot call the kd-tree.

pykdtree runs queries in OpenMP threads. For a query this small that gains nothing, and OpenMP's
idle threads then spin on the other core after every query (measured: process CPU time twice the
wall time). So, unless the user chose otherwise, OpenMP gets one thread; the variable has to be set
before the OpenMP runtime loads, that is before pykdtree is first imported.
"""

from __future__ import annotations

import os

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before pykdtree loads the OpenMP runtime

from pykdtree.kdtree import KDTree


def point_tree(points: np.ndarray) -> KDTree:
    """A kd-tree over points (M, 2) (metres, the caller's frame). Its ``query(pts, k=1,
    distance_upper_bound=inf)`` takes float64 points (N, 2) and gives distances (m) and indices
    (uint32) of the ``k`` nearest, as scipy's ``cKDTree.query``: shape (N,) for k = 1, else (N, k);
    where fewer lie within ``distance_upper_bound``, distance inf and index M."""
    return KDTree(np.ascontiguousarray(points, dtype=np.float64))
