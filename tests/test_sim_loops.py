"""The world's loops from ground truth (service.sim.loops): holes, loops driven, loops a map closed."""

from __future__ import annotations

import itertools
import math

import numpy as np
import shapely

from mapper.se2 import inverse, transform_points
from service.evaluate import Track, true_outlines
from service.sim.loops import closures, enclosed, loops_closed, returns, world_holes
from service.sim.world import load_world, parse_world

LAB = load_world("lab")
HOLES = world_holes(LAB)


def _index_of(x: float, y: float) -> int:
    (n,) = [i for i, h in enumerate(HOLES) if h.covers(shapely.Point(x, y))]
    return n


ISLAND_EAST = _index_of(11.8, 4.5)  # the table island at (10.6-13.0, 3.7-5.3) with its chairs
ISLAND_NORTH = _index_of(5.0, 10.4)


def _ring(x0: float, y0: float, x1: float, y1: float, turns: float = 1.0, step: float = 0.02) -> np.ndarray:
    """A path round the rectangle, counter-clockwise from its south-west corner, ``turns`` times."""
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    one = np.vstack([np.linspace(a, b, max(2, int(math.hypot(*(b - a)) / step)), endpoint=False)
                     for a, b in itertools.pairwise(corners)])
    n = int(len(one) * turns)
    return np.vstack([one] * (int(turns) + 1))[: n + 1]


def test_the_lab_has_its_two_table_islands_and_three_walls_between_doorways_as_holes():
    assert len(HOLES) == 5
    assert ISLAND_EAST != ISLAND_NORTH
    # An office with no free-standing obstacle and no second way round has none.
    box = parse_world({"schema": "asrmap/world/1", "start": [1, 1, 0],
                       "loops": [[[0, 0], [4, 0], [4, 3], [0, 3]]]})
    assert world_holes(box) == []


def test_a_path_round_a_table_island_drives_that_loop_alone():
    w = returns(_ring(9.9, 2.6, 13.7, 6.4), HOLES)
    expected = np.zeros(len(HOLES), dtype=int)
    expected[ISLAND_EAST] = 1
    assert [list(v) for v in w] == [list(expected)]
    # Clockwise is the same loop the other way; twice round is not a second loop.
    cw = returns(_ring(9.9, 2.6, 13.7, 6.4)[::-1], HOLES)
    twice = returns(_ring(9.9, 2.6, 13.7, 6.4, turns=2.0), HOLES)
    assert [list(v) for v in cw] == [list(-expected)]
    assert loops_closed(twice, w) == (1, 1)


def test_going_out_and_back_the_same_way_drives_no_loop():
    out = np.column_stack([np.linspace(4.0, 15.0, 600), np.full(600, 6.8)])
    assert len(returns(np.vstack([out, out[::-1]]), HOLES)) == 0
    # Three quarters of the way round the island and back: no loop either.
    part = _ring(9.9, 2.6, 13.7, 6.4, turns=0.75)
    assert len(returns(np.vstack([part, part[::-1]]), HOLES)) == 0


def test_once_round_the_corridor_turns_round_every_hole_inside_it():
    w = returns(_ring(0.8, 0.8, 17.2, 14.2), HOLES)
    # The ring's corner at (17.2, 14.2) is outside the L (corridor inner runs at x 8.4-10): this is
    # a pure geometry test of the count, not of a drivable path.
    assert [list(v) for v in w] == [[1] * len(HOLES)]


def _ring_truth(ring: np.ndarray) -> Track:
    t = np.arange(len(ring)) * 0.05
    step = np.diff(ring, axis=0, append=2 * ring[-1:] - ring[-2:-1])
    return Track(t, [(float(x), float(y), float(h))
                     for (x, y), h in zip(ring, np.arctan2(step[:, 1], step[:, 0]), strict=True)])


def _asr(truth: Track, k: int, created: float, box: tuple | shapely.Polygon) -> dict:
    """An ASR document entry whose outline is ``box`` (a box's bounds or a polygon, world frame), its
    frame the true pose then."""
    inv = inverse(truth.at(created))
    b = box if isinstance(box, shapely.Polygon) else shapely.box(*box)
    return {"id": k, "created": created,
            "boundary": transform_points(inv, np.array(b.exterior.coords)[:-1]).tolist(),
            "centre": transform_points(inv, np.array([b.centroid.coords[0]]))[0].tolist()}


def _outlines(doc: dict, truth: Track) -> dict:
    """Each ASR's true outline, the truth standing in for the odometry (no drift)."""
    return true_outlines(doc["asrs"], truth, truth)[1]


def test_a_closure_closes_the_loop_the_robot_drove_between_leaving_and_reentering_the_space():
    ring = _ring(9.9, 2.6, 13.7, 6.4)
    truth = _ring_truth(ring)
    corner = (9.4, 2.1, 10.6, 3.3)  # a space round the ring's start, its south-west corner
    leave = float(truth.t[np.flatnonzero(ring[:, 0] > 10.6)[0]])
    back = float(truth.t[-40])
    doc = {"asrs": [_asr(truth, 1, 0.0, corner), _asr(truth, 2, leave, (10.6, 2.1, 14.2, 3.3)),
                    _asr(truth, 3, back, corner)]}
    crossings = [(leave, 1, 2), (back, 2, 3)]
    closed = closures(doc, ((3, 1, back),), crossings, truth, _outlines(doc, truth), HOLES)
    driven = returns(ring, HOLES)
    assert [list(v) for v in closed] == [list(driven[0])]
    assert loops_closed(driven, closed) == (1, 1)
    # Out of the space and straight back in: the closure closes no loop.
    assert len(closures(doc, ((3, 1, back),), [(back - 1.0, 1, 2), (back, 2, 3)], truth,
                        _outlines(doc, truth), HOLES)) == 0
    # Two loops driven, one closed.
    both = np.vstack([driven, returns(_ring(3.2, 8.5, 6.8, 11.9), HOLES)])
    assert loops_closed(both, closed) == (2, 1)


def test_a_closure_closes_the_loop_through_the_space_round_an_island_not_across_the_island():
    # The room round the east island is one space on three sides (ASR 1, south and west, and its
    # duplicate 3, west and north) and another ASR on the fourth (2, east), as the room splits in
    # `lab`. The robot leaves 1 eastwards into 2 and comes back into 3 on the north side: the map
    # knows it went round the island, and the loop joined up through the space says so, where a
    # straight step back across the east side would not.
    ring = _ring(9.9, 2.6, 13.7, 6.4)
    truth = _ring_truth(ring)
    south, west = shapely.box(9.4, 2.1, 13.2, 3.3), shapely.box(9.4, 2.1, 10.6, 6.9)
    north = shapely.box(9.4, 5.7, 13.2, 6.9)
    leave = float(truth.t[np.flatnonzero(ring[:, 0] > 13.2)[0]])
    back = float(truth.t[np.flatnonzero((ring[:, 1] > 6.3) & (ring[:, 0] < 13.2))[0]])
    doc = {"asrs": [_asr(truth, 1, 0.0, south.union(west)), _asr(truth, 2, leave, (13.2, 2.1, 14.2, 6.9)),
                    _asr(truth, 3, back, west.union(north))]}
    doc["asrs"][2]["duplicate_of"] = 1
    crossings = [(leave, 1, 2), (back, 2, 3)]
    closed = closures(doc, ((3, 1, back),), crossings, truth, _outlines(doc, truth), HOLES)
    driven = returns(ring, HOLES)
    assert [list(v) for v in closed] == [list(driven[0])]
    assert loops_closed(driven, closed) == (1, 1)
    # Had 3 not been matched with 1, the crossing into it would close nothing.
    del doc["asrs"][2]["duplicate_of"]
    assert len(closures(doc, (), crossings, truth, _outlines(doc, truth), HOLES)) == 0


def test_an_island_inside_one_asr_or_two_joined_ones_needs_no_closure():
    ring = _ring(9.9, 2.6, 13.7, 6.4)
    truth = _ring_truth(ring)
    room = {"asrs": [_asr(truth, 1, 0.0, (9.5, 2.2, 14.2, 6.9))]}
    island = np.zeros((1, len(HOLES)), dtype=int)
    island[0, ISLAND_EAST] = 1
    assert enclosed(_outlines(room, truth), [], HOLES).tolist() == island.tolist()
    assert loops_closed(returns(ring, HOLES), enclosed(_outlines(room, truth), [], HOLES)) == (1, 1)
    # Outlines over half the island each, not joined, do not hold a loop round it.
    halves = {"asrs": [_asr(truth, 1, 0.0, (9.5, 2.2, 11.8, 6.9)),
                       _asr(truth, 2, 10.0, (11.8, 2.2, 14.2, 6.9))]}
    assert len(enclosed(_outlines(halves, truth), [], HOLES)) == 0
    # The room split in two, the halves joined by one transition: one rigid map round the island.
    assert enclosed(_outlines(halves, truth), [(10.0, 1, 2)], HOLES).tolist() == island.tolist()
