"""Surfaces, exits and views on synthetic scans with exact answers (ray-cast in tests/raycast.py).

World frame = the robot's pose (0, 0, 0) unless a test says otherwise; the scans carry the P2DX
laser offset (x 17 mm, y 8 mm) that the default MapperParams undo.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import shapely
from raycast import box, cast

from mapper.asr_builder import AsrBuilder
from mapper.exits import find_covers
from mapper.lines import extract_surfaces, scan_points
from mapper.mapper import Mapper
from mapper.params import MapperParams
from mapper.se2 import compose, inverse, transform_points
from mapper.types import Odometry, Scan
from mapper.view import View, build_view

P = MapperParams()
LASER = (P.laser_x, P.laser_y)
WALL = 0.15  # wall thickness (m)


def _view(walls, pose=(0.0, 0.0, 0.0), **kw):
    scan = cast(walls, pose, laser=LASER, **kw)
    surf = extract_surfaces(scan_points(scan, P), P)
    return surf, build_view(surf, P, find_covers(surf, P))


def _world(pose, segs):
    return transform_points(pose, np.asarray(segs).reshape(-1, 2)).reshape(-1, 2, 2)


def _doorway_world():
    """Room x in [-1, 2.5], y in [-2, 2] with a 0.9 m doorway (y in [-0.45, 0.45]) in its x = 2.5 wall,
    and a second room x in [2.65, 6], y in [-3, 3] behind it."""
    x, t = 2.5, WALL
    room = [
        ((-1, -2), (x, -2)),
        ((x, -2), (x, -0.45)),
        ((x, 0.45), (x, 2)),
        ((x, 2), (-1, 2)),
        ((-1, 2), (-1, -2)),
    ]
    jambs = [((x, -0.45), (x + t, -0.45)), ((x, 0.45), (x + t, 0.45))]
    second = [((x + t, -0.45), (x + t, -3)), ((x + t, 0.45), (x + t, 3)), ((6, -3), (6, 3))]
    second += [((x + t, -3), (6, -3)), ((x + t, 3), (6, 3))]
    return room + jambs + second


def _matches(seg, a, b, tol):
    a, b = np.asarray(a), np.asarray(b)
    d1 = max(np.hypot(*(seg[0] - a)), np.hypot(*(seg[1] - b)))
    d2 = max(np.hypot(*(seg[0] - b)), np.hypot(*(seg[1] - a)))
    return min(d1, d2) <= tol


def test_straight_wall_is_one_surface():
    surf, _ = _view([((2, -5), (2, 5))])
    assert len(surf) == 1
    assert np.allclose(surf.segments[0, :, 0], 2.0, atol=0.01)


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (0.3, -0.6, 0.2), (0.0, 1.0, -0.3)])
def test_room_with_one_doorway_gives_one_exit_at_the_doorway(pose):
    _, view = _view(_doorway_world(), pose)
    exits = _world(pose, view.exits)
    assert len(exits) == 1
    assert _matches(exits[0], (2.5, -0.45), (2.5, 0.45), 0.05), exits[0]


def test_second_room_seen_through_the_doorway_is_eliminated():
    surf, view = _view(_doorway_world())
    assert (surf.segments[..., 0] > 2.7).any()  # the scan does see the second room...
    assert (view.surfaces[..., 0] <= 2.5 + 0.05).all()  # ...but no surface of it is in the view
    assert view.polygon.bounds[2] <= 2.5 + 0.05
    assert "exit" in view.labels


def test_table_legs_0_3_m_apart_give_no_exit():
    # a table (legs 4 cm thick, 0.3 m apart) across a 1.2 m wide alcove: the only way on is between legs
    legs = []
    for cy in (-0.45, -0.15, 0.15, 0.45):
        legs += box(2.0 - 0.02, cy - 0.02, 2.0 + 0.02, cy + 0.02)
    walls = [
        ((-1, -2), (2, -2)),
        ((2, -2), (2, -0.6)),
        ((2, 0.6), (2, 2)),
        ((2, 2), (-1, 2)),
        ((-1, 2), (-1, -2)),
    ]
    walls += [((2, -0.6), (3, -0.6)), ((2, 0.6), (3, 0.6)), ((3, -0.6), (3, 0.6))]
    _, view = _view(walls + legs)
    assert len(view.exits) == 0
    # what lies behind the legs is cut off by the closed gaps between them
    assert not view.polygon.contains(shapely.Point(2.5, 0.0))
    assert view.polygon.contains(shapely.Point(1.5, 0.0))


def test_t_junction_gives_exits_where_the_side_corridors_open():
    # stem corridor y in [-1.2, 1.2] up to x = 4; the 1.5 m wide cross corridor x in [4, 5.5] runs along y.
    # 0.5° beams from 2.5 m before the junction: the stem walls' last returns lie within 3 cm of
    # the corners (an occluding end is only as exact as the beam spacing where it is seen).
    walls = [((-1, -1.2), (4, -1.2)), ((4, -1.2), (4, -8)), ((-1, 1.2), (4, 1.2)), ((4, 1.2), (4, 8))]
    walls += [((5.5, -8), (5.5, 8)), ((-1, -1.2), (-1, 1.2))]
    pose = (1.5, 0.0, 0.0)
    _, view = _view(walls, pose, n=361)
    exits = _world(pose, view.exits)
    assert len(exits) == 2
    right = [e for e in exits if e[:, 1].mean() < 0]
    left = [e for e in exits if e[:, 1].mean() > 0]
    assert len(right) == 1 and len(left) == 1
    assert _matches(right[0], (4, -1.2), (5.5, -1.2), 0.05), right
    assert _matches(left[0], (4, 1.2), (5.5, 1.2), 0.05), left


def test_every_view_edge_is_labelled_and_the_rear_is_unknown():
    _, view = _view(_doorway_world())
    assert len(view.labels) == len(view.vertices)
    assert set(view.labels) <= {"surface", "exit", "unknown"}
    rear = int(np.argmin(view.vertices[:, 0]))
    assert view.labels[rear] == "unknown" and view.labels[rear - 1] == "unknown"
    assert view.polygon.is_valid and view.polygon.contains(shapely.Point(0, 0))


def test_full_turn_in_place_closes_the_room():
    room = box(-2, -1.5, 3, 2.5)  # 20 m² of free space
    m = Mapper(MapperParams())
    steps = 40
    for i in range(steps + 1):
        th = math.remainder(2 * math.pi * i / steps, 2 * math.pi)
        t = 0.1 * i
        m.add_odometry(Odometry(t, 0.0, 0.0, th))
        m.add_scan(cast(room, (0.0, 0.0, th), laser=LASER, t=t))
    assert len(m.asrs) == 1
    asr = m.asrs[m.current]
    assert "unknown" not in asr.edges, asr.edges
    assert asr.exits == []
    assert asr.area == pytest.approx(20.0, rel=0.05)
    assert asr.polygon.is_valid


def test_asr_exit_ids_are_stable_as_the_robot_looks_around():
    m = Mapper(MapperParams())
    world = _doorway_world()
    ids = []
    for i, th in enumerate(np.linspace(-0.4, 0.4, 9)):
        m.add_odometry(Odometry(0.1 * i, 0.0, 0.0, float(th)))
        m.add_scan(cast(world, (0.0, 0.0, float(th)), laser=LASER, t=0.1 * i))
        ids.append([e.id for e in m.asrs[1].exits])
    assert ids[-1] == ["1/0"]
    assert all(i == ["1/0"] for i in ids)
    e = m.asrs[1].exits[0]
    frame = (0.0, 0.0, -0.4)  # the ASR frame is the robot pose at the first scan
    assert _matches(_world(frame, [e.a, e.b])[0], (2.5, -0.45), (2.5, 0.45), 0.05)


@pytest.mark.parametrize("ranges", [np.full(181, 81.91), np.full(181, 0.001), np.full(181, np.nan)],
                         ids=["every beam no return", "laser covered", "NaN readings"])
def test_a_laser_that_sees_nothing_neither_crashes_nor_invents_surfaces(ranges):
    m = Mapper(MapperParams())
    for k in range(40):
        m.add_odometry(Odometry(0.1 * k, 0.05 * k, 0.0, 0.0))
        m.add_scan(Scan(0.1 * k, ranges, -math.pi / 2, math.pi / 180, 8.0))
    (asr,) = m.document()["asrs"]
    assert "surface" not in asr["edges"] and not asr["exits"]


@pytest.mark.parametrize(("make", "message"), [
    (lambda: Odometry(0.0, math.nan, 0.0, 0.0), "Odometry.x is nan: expected a finite number"),
    (lambda: Odometry(math.inf, 0.0, 0.0, 0.0), "Odometry.t is inf"),
    (lambda: Scan(0.0, np.ones(181), -1.57, 0.0, 8.0), "Scan.angle_increment is 0.0 rad for 181 beams"),
    (lambda: Scan(0.0, np.ones(181), -1.57, 0.1, 8.0), "within one turn"),
    (lambda: Scan(0.0, np.ones((2, 3)), -1.57, 0.01, 8.0), "expected one row of ranges"),
    (lambda: Scan(0.0, np.ones(181), -1.57, 0.01, -1.0), "Scan.max_range is -1.0"),
])
def test_readings_that_are_not_readings_are_refused_with_the_field_named(make, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        make()


def test_crossing_a_doorway_makes_one_asr_not_one_per_scan(tmp_path):
    """Standing in a doorway, the exit across it runs through the robot: it must not truncate the
    view, or the new ASR's first view is a sliver behind the robot whose front the next scan
    crosses, making another ASR every scan until the robot clears the doorway (6 in 0.6 s here)."""
    from service.replay import replay
    from tests.synthetic_runs import ROOMS_WAYPOINTS, drifting, path, two_rooms, write_carmen

    truth = path(ROOMS_WAYPOINTS, laps=1.0, step=0.05)
    log = tmp_path / "rooms-raw.clf"
    write_carmen(log, two_rooms(), truth, drifting(truth))
    created = [a["created"] for a in replay(log).document["asrs"]]
    assert len(created) == 3, created  # room, corridor, room
    assert min(np.diff(created)) > 2.0, created




def _side_doorway_run(y0: float):
    """Along a corridor (y 4..5.8), then down through a 0.9 m doorway in its side wall into a room
    (x 5..10, y 0..4), exact odometry; ``y0`` (the corridor leg's y) moves where viewpoints fall.
    Returns the mapper, the true start pose and the room's inside (world frame)."""
    from tests.synthetic_runs import drive_mapper, path

    corridor = [((0.0, 5.8), (10.0, 5.8)), ((0.0, 4.0), (7.05, 4.0)), ((7.95, 4.0), (10.0, 4.0)),
                ((0.0, 4.0), (0.0, 5.8)), ((10.0, 4.0), (10.0, 5.8))]
    room = [((5.0, 0.0), (10.0, 0.0)), ((5.0, 0.0), (5.0, 4.0)), ((10.0, 0.0), (10.0, 4.0))]
    truth = path([(1.5, y0), (7.5, y0), (7.5, 2.0)], step=0.05)
    m = Mapper(P)
    drive_mapper(m, corridor + room, truth, scale_error=0.0, heading_per_m=0.0)
    return m, truth[0], shapely.box(5.0, 0.0, 10.0, 3.9)


@pytest.mark.parametrize("y0", [4.91, 4.96, 5.03, 5.06, 5.07])
def test_a_view_from_a_doorway_is_not_unioned_so_the_room_beyond_stays_out_of_the_corridor(y0):
    """A viewpoint falling within rear_closure of the doorway's line sees through it: the exit
    across the doorway runs through the robot and does not bound the view (the test above), or the
    jambs are already beside the laser and the scan shows no gap. Unioned, such a view swallowed
    1.2-3.1 m² of the room into the corridor's ASR at 9 of 20 offsets of y0 (in the simulated office,
    seed 2, a whole room: the robot never left the corridor's ASR and 4 of 6 rooms were never
    entered). It is not unioned."""
    m, start, inside = _side_doorway_run(y0)
    assert m.current == max(m.asrs), "the robot must end in the ASR made when it entered the room"
    for a in m.asrs.values():
        if a.id != m.current:
            world = shapely.Polygon(transform_points(compose(start, a.origin), a.boundary))
            assert world.intersection(inside).area < 0.5, (a.id, world.intersection(inside).area)


def test_a_wide_occlusion_whose_end_lies_near_the_crossing_is_not_the_entrance():
    """``lab`` seed 1, ASR 12 (recorded): made at the corridor's south-west corner, the robot facing
    south (+x); the first view's only exit runs 7.2 m to the far end of the south corridor, its end
    0.8 m from where the robot came in and the crossing 0.8 m beyond that end along the chord.
    Taken as the entrance, the south corridor looked explored and 3 of 7 regions were never
    entered."""
    from mapper.mapper import entrance
    from mapper.types import Exit

    at = (-0.0199, 0.0001)  # the crossing, ASR 12's frame (m)
    chord = Exit("12/0", (1.2654, 7.8886), (0.1127, 0.7901))
    assert entrance([chord], at, 0.6) is None
    # The same chord laid across the crossing, and a doorway-wide exit as near as the chord's end
    # (narrow exits are not tested): each is the entrance.
    across = Exit("12/0", (-0.3, 7.0), (-0.3, -0.2))
    assert entrance([across], at, 0.6) is across
    door = Exit("12/1", (1.4, 0.9), (0.5, 0.9))
    assert entrance([door], at, 0.6) is door
    assert entrance([chord, door], at, 0.6) is door


@pytest.mark.xfail(strict=True, reason="known fault: a doorway beside the path is taken as the entrance")
@pytest.mark.parametrize("y0", [4.98, 5.00])
def test_a_doorway_beside_the_path_is_not_taken_as_the_way_back(y0):
    """Known fault, left open (docs/simulation-faults.md, "Known faults left open"): a corridor ASR
    created a metre before the side doorway takes the doorway as its entrance (the nearest exit
    within two passage widths of where it was entered that does not face ahead), so walking
    through the doorway re-enters the ASR before it. Requiring the entrance to run along the exit
    crossed fixes this case, but in the simulated worlds it rejected true entrances, and three of
    nine runs ended early."""
    m, _, _ = _side_doorway_run(y0)
    assert m.current == max(m.asrs)


def test_exit_ends_inserted_into_a_ring_pinched_within_rounding_leave_it_valid():
    # A ring whose vertex D lies 1e-15 m from its edge AB (the union can leave such a pinch):
    # valid, but the exits' ends projected onto AB, rounded, cross D (found on the Intel log).
    from mapper.asr_builder import AsrBuilder

    a, b = np.array([10.0, -7.0]), np.array([14.022741662069002, -4.030564107401152])
    ring = [a, b, (12.241080126509694, -1.61691911015975), (11.81023374793105, -5.6637538483305185),
            (8.218338464440691, -4.586355002758598)]
    builder = AsrBuilder(1, 0.0, (0.0, 0.0, 0.0), MapperParams())
    builder.polygon = shapely.Polygon(ring)
    assert builder.polygon.is_valid
    nrm = np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a)) * 0.01
    ends = [a + f * (b - a) + nrm for f in (0.2, 0.4, 0.5, 0.7)]
    builder.exit_segments = np.array([[ends[0], ends[1]], [ends[2], ends[3]]])
    assert shapely.Polygon(builder._ring()).is_valid


def test_a_clip_that_comes_apart_at_a_neck_keeps_what_the_asr_held():
    # A duplicate's growth is clipped to its match's area; what it held before stays. The union of
    # the polygon before with the clipped growth came apart where two parts of it meet (lab seed 4,
    # recorded in tests/data), and the part round the origin alone was kept: 27.9 -> 7.6 m², its
    # cycle's match's centre then 3 m outside it.
    d = json.loads((Path(__file__).parent / "data" / "clip_at_a_neck.json").read_text())
    before = shapely.Polygon(d["before"])
    area = shapely.Polygon(d["area"]["exterior"], d["area"]["holes"])
    b = AsrBuilder(49, 0.0, (0.0, 0.0, 0.0), MapperParams())
    b.polygon = shapely.Polygon(d["polygon"])
    assert b.clip_growth(before, area, tuple(d["robot"]))
    assert b.polygon.area >= before.area - 1e-9
    assert b.polygon.covers(before.representative_point()) and b.polygon.is_valid


def test_of_two_equally_short_covers_to_a_shared_corner_the_nearer_surface_in_the_sweep_wins():
    # Surfaces 1 and 2 meet at the corner C = (2, 0), the closest point of both to the occluding end
    # P = (0, 0): the cover P-C lands on surface 1's end (t = 1), the nearer across the gap.
    from mapper.exits import _shortest

    seg = np.array([[[-1.0, 1.0], [-0.5, 0.2]], [[3.0, 1.0], [2.0, 0.0]], [[2.0, 0.0], [3.0, -1.0]]])
    best, length, q, t = _shortest(seg, np.array([-0.5, -0.5]), np.zeros((1, 2)), np.array([0]),
                                   np.array([True]), MapperParams().visibility_tolerance)
    assert best.tolist() == [1] and t.tolist() == [1.0]
    assert length[0] == pytest.approx(2.0) and q[0].tolist() == [2.0, 0.0]


def _corridor_view(x0: float, x1: float, wall_exits: tuple[float, float] | None) -> View:
    """A view (robot at the origin, frame aligned with the corridor, y -0.9..0.9) of the corridor from
    x0 to x1, its far end an exit across it; ``wall_exits``: from where to where (x) both walls were
    too sparse to fit and were taken for exits (joined across the end), as far, grazing views are."""
    south, north = -0.9, 0.9
    if wall_exits is None:
        v = [(x0, south), (x1, south), (x1, north), (x0, north)]
        labels = ["surface", "exit", "surface", "unknown"]
        surfaces = [((x0, south), (x1, south)), ((x1, north), (x0, north))]
        exits = [((x1, south), (x1, north))]
    else:
        a, b = wall_exits
        v = [(x0, south), (a, south), (b, south), (b, north), (a, north), (x0, north)]
        labels = ["surface", "exit", "exit", "exit", "surface", "unknown"]
        surfaces = [((x0, south), (a, south)), ((a, north), (x0, north))]
        exits = [((a, south), (b, south)), ((b, south), (b, north)), ((b, north), (a, north))]
    v = np.array(v, dtype=float)
    return View(v, labels, shapely.Polygon(v), np.array(surfaces, dtype=float), np.array(exits, dtype=float))


def test_an_exit_along_a_wall_a_later_view_sees_is_dropped_and_the_wall_becomes_surface():
    """A corridor's walls seen far and at a grazing angle are too sparse to fit: the gaps between their
    returns are exits along the walls, joined across the corridor's end into one run of exit edges.
    A nearer view sees the walls as surfaces. The stored exits they cover are dropped: kept, they
    labelled those walls exit (an edge along both is one), and the whole U became one exit whose
    chord crossed the corridor where the walls were first too sparse, with any doorway in either
    wall inside it (the simulated office, seed 3: room 5 was never entered)."""
    b = AsrBuilder(1, 0.0, (0.0, 0.0, 0.0), P)
    b.add_view(_corridor_view(-0.3, 6.0, wall_exits=(3.0, 6.0)), (0.0, 0.0, 0.0))
    assert len(b.asr.exits) == 1 and b.asr.exits[0].midpoint[0] == pytest.approx(3.0, abs=0.05)
    # from 3 m on, the walls are surfaces to the end (and the view adds a strip at the rear)
    assert b.add_view(_corridor_view(-4.0, 3.0, wall_exits=None), (3.0, 0.0, 0.0))
    (e,) = b.asr.exits
    assert e.midpoint == pytest.approx((6.0, 0.0), abs=0.05)  # the corridor's end, not its middle
    v = b.asr.boundary
    nxt = np.roll(v, -1, axis=0)
    along_walls = np.isclose(np.abs(v[:, 1]), 0.9) & np.isclose(v[:, 1], nxt[:, 1])
    assert set(np.array(b.asr.edges)[along_walls]) == {"surface"}


def _room_view(x0: float, surfaces) -> View:
    """A hand-made view (robot frame, the robot at the ASR's origin) of the room x in [x0, 2.5],
    y in [-2, 2] with a 0.9 m doorway (y in [-0.45, 0.45]) in its x = 2.5 wall; ``surfaces``: the
    segments it saw."""
    v = np.array([(x0, -2.0), (2.5, -2.0), (2.5, -0.45), (2.5, 0.45), (2.5, 2.0), (x0, 2.0)])
    labels = ["surface", "surface", "exit", "surface", "surface", "surface"]
    return View(v, labels, shapely.Polygon(v), np.array(surfaces, dtype=float),
                np.array([((2.5, -0.45), (2.5, 0.45))]))


@pytest.mark.parametrize("crossed", [True, False])
def test_a_doorway_the_robot_crossed_is_not_explained_away_by_the_walls_beside_it(crossed):
    """The walls either side of a doorway, each seen reaching 0.1 m into it, and a stray return at a
    jamb cover three of the five points the covering test takes along the doorway. An exit nobody
    crossed is then taken for a wall seen too sparsely (the rule that keeps the office's corridor
    walls from becoming exits), even one with a transition: a new ASR's entrance is the exit
    nearest to where the robot came in, and in ``office`` seed 4 that was the room's wall beside
    the door. One the robot was seen to cross keeps its exit and transition (``lab`` seed 3: a view
    from 7 m dropped the south door this way, and its transition to the corridor; the next view
    through the door swallowed the corridor)."""
    b = AsrBuilder(1, 0.0, (0.0, 0.0, 0.0), P)
    walls = [((-1.0, -2.0), (2.5, -2.0)), ((2.5, -2.0), (2.5, -0.45)), ((2.5, 0.45), (2.5, 2.0)),
             ((2.5, 2.0), (-1.0, 2.0)), ((-1.0, 2.0), (-1.0, -2.0))]
    b.add_view(_room_view(-1.0, walls), (0.0, 0.0, 0.0))
    (door,) = b.asr.exits
    assert door.midpoint == pytest.approx((2.5, 0.0), abs=0.01)
    door.to = 2
    if crossed:
        b.crossed.add(door.id)
    seen = [((2.5, -2.0), (2.5, -0.35)), ((2.5, 0.35), (2.5, 2.0)), ((2.5, -0.12), (2.5, -0.08)),
            ((-1.5, -2.0), (-1.5, 2.0))]
    assert b.add_view(_room_view(-1.5, seen), (0.0, 0.0, 0.0))  # it grows at the back: relabelled
    kept = [(e.id, e.to) for e in b.asr.exits if e.midpoint == pytest.approx((2.5, 0.0), abs=0.05)]
    assert kept == ([(door.id, 2)] if crossed else [])


def test_the_mapper_records_the_exit_the_robot_crossed_not_the_entrance_it_guessed():
    """Walking from the corridor through the side doorway: the corridor's exit the path cut is
    recorded as crossed; the room's entrance (the nearest exit to where the robot came in) is not."""
    m, _, _ = _side_doorway_run(4.91)
    corridor, room = min(m.asrs), m.current
    assert room != corridor
    assert m._builders[corridor].crossed == {e.id for e in m.asrs[corridor].exits if e.to == room}
    assert len(m._builders[corridor].crossed) == 1
    assert m._builders[room].crossed == set()


@pytest.mark.xfail(strict=True, reason="known fault: a side corridor's mouth seen down a corridor is open")
def test_a_side_corridors_mouth_seen_down_the_corridor_is_an_exit():
    """Known fault, left open (docs/simulation-faults.md, "Known faults left open"). `lab` seed 43's
    corner (world frame, m): a 1.6 m corridor (x in [8.4, 10]) runs south into one running east
    (y in [7.4, 9]); from 0.45 m off its west wall, looking down it, that wall is seen at a grazing
    angle, its points too far apart to join, and the covers between them (0.6-0.8 m: exits) cross
    the corner's cover in the sweep. The earlier one is kept, so the mouth (the corner to the west
    wall across it) is left an open gap, an unknown region the explorer retired unvisited (drifted
    ASRs covered the space beyond it): the corridor running east was never entered. Two fixes
    pass this test and were not kept (history, eleventh session): keeping the nearer of two
    crossing covers closed false pairs on Intel corrected and Intel raw; a cover landing on a
    point surface spanning all of it (so the two nest) cut Intel raw's recall from 80 % to 25 %."""
    walls = [((8.4, 15.0), (8.4, 7.4)), ((8.4, 7.4), (16.4, 7.4)), ((10.0, 9.0), (10.0, 15.0)),
             ((10.0, 9.0), (16.4, 9.0)), ((8.4, 15.0), (10.0, 15.0))]
    pose = (8.85, 13.15, math.radians(-99.0))
    _, view = _view(walls, pose)
    exits = _world(pose, view.exits)
    mouth = [e for e in exits if min(np.hypot(*(e - (10.0, 9.0)).T)) < 0.25]
    assert len(mouth) == 1, exits
    assert abs(mouth[0][:, 1] - 9.0).max() < 0.5 and np.ptp(mouth[0][:, 0]) > 1.4, mouth
    # Beyond the mouth the view ends: the east-west corridor is outside it.
    beyond = transform_points(inverse(pose), np.array([[9.2, 8.2], [10.3, 7.6]]))
    assert not shapely.contains_xy(view.polygon, beyond[:, 0], beyond[:, 1]).any()
