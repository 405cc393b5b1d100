"""Ray casting: exact ranges on known geometry, noise, no-return, mounting offset, speed."""

from __future__ import annotations

import math

import numpy as np
import shapely

from service.sim.raycast import LMS_MAX_RANGE, RayCaster, cast
from service.sim.world import parse_world

ANGLES = np.radians(np.arange(-90.0, 90.5, 1.0))


def wall_world(door: bool = False):
    wall = {"from": [2.0, -3.0], "to": [2.0, 3.0]}
    if door:
        wall["doors"] = [{"at": 3.0, "width": 0.9}]
    return parse_world({"schema": "asrmap/world/1", "start": [0.0, 0.0, 0.0], "walls": [wall]})


def test_a_wall_2_m_ahead_reads_2_m_within_the_noise():
    rc = RayCaster(wall_world(), sigma=0.01, mount=(0.0, 0.0, 0.0), seed=1)
    r = rc.scan((0.0, 0.0, 0.0), ANGLES)
    assert abs(r[90] - 2.0) < 0.05
    # Beam at angle a meets x = 2 at 2 / cos(a) while that is within the 3 m half-wall.
    a = ANGLES[60:121]
    assert np.all(np.abs(r[60:121] - 2.0 / np.cos(a)) < 0.05)


def test_a_doorway_reads_through_to_max_range():
    rc = RayCaster(wall_world(door=True), sigma=0.0, mount=(0.0, 0.0, 0.0))
    r = rc.scan((0.0, 0.0, 0.0), ANGLES)
    assert r[90] == LMS_MAX_RANGE  # straight through the gap (y in [-0.45, 0.45]) to nothing
    assert abs(r[90 + 20] - 2.0 / math.cos(math.radians(20))) < 1e-9  # the wall beside the door


def test_beyond_max_range_is_the_no_return_value():
    rc = RayCaster(wall_world(), sigma=0.01, max_range=1.5, mount=(0.0, 0.0, 0.0))
    assert np.all(rc.scan((0.0, 0.0, 0.0), ANGLES) == 1.5)


def test_mounting_offset_is_applied_in_the_robot_frame():
    rc = RayCaster(wall_world(), sigma=0.0)  # laser 17 mm forward of the robot centre
    r = rc.scan((0.0, 0.0, 0.0), ANGLES)
    assert abs(r[90] - (2.0 - 0.017)) < 1e-9
    # Turned left by 90 degrees, the wall is to the right: beam -90 deg, laser 17 mm to the left.
    r = rc.scan((0.0, 0.0, math.pi / 2), ANGLES)
    assert abs(r[0] - (2.0 + 0.008)) < 1e-9


def test_circles_are_hit_at_their_near_side():
    segs = np.zeros((0, 4))
    r = cast((0.0, 0.0), np.array([0.0, 0.5]), segs, np.array([[3.0, 0.0, 0.5]]))
    assert abs(r[0] - 2.5) < 1e-12 and r[1] == np.inf


def test_matches_shapely_on_random_geometry():
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 8, (40, 2))
    segs = np.hstack([p, p + rng.normal(0, 1, (40, 2))])
    circles = np.hstack([rng.uniform(0, 8, (8, 2)), np.full((8, 1), 0.1)])
    geom = shapely.union_all([shapely.LineString(s.reshape(2, 2)) for s in segs]
                             + [shapely.Point(c[:2]).buffer(c[2], quad_segs=256) for c in circles])
    o = np.array([4.0, 4.2])
    dirs = 0.3 + np.radians(np.arange(0.0, 360.0, 2.0))
    r = cast(tuple(o), dirs, segs, circles, 8.0)
    for a, got in zip(dirs, r, strict=True):
        hit = shapely.LineString([o, o + 20 * np.array([math.cos(a), math.sin(a)])]).intersection(geom)
        ref = math.inf if hit.is_empty else shapely.distance(shapely.Point(o), hit)
        ref = math.inf if ref > 8.0 else ref
        assert (math.isinf(ref) and math.isinf(got)) or abs(ref - got) < 2e-3


def test_source_plugs_into_the_laser_emulator_signature():
    rc = RayCaster(wall_world(), sigma=0.0, mount=(0.0, 0.0, 0.0))
    src = rc.source(lambda t: (t, 0.0, 0.0))
    assert abs(src(1.0, np.array([0.0]))[0] - 1.0) < 1e-9
