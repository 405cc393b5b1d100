"""End-to-end synthetic runs: a robot driven through a wall world, scans ray cast, odometry drifting.

The true poses are known exactly, so the evaluation of :mod:`service.evaluate` scores the map.
"""

from __future__ import annotations

import math

from mapper.se2 import Pose, between, compose
from mapper.types import Odometry
from service.evaluate import Track
from tests.raycast import box, cast


def corridor_loop() -> list:
    """A 2.5 m wide corridor around a 7 m x 5 m block (outer 12 m x 10 m): walls as segments."""
    return box(0.0, 0.0, 12.0, 10.0) + box(2.5, 2.5, 9.5, 7.5)


#: The corridor's centreline, counter-clockwise from the south-west corner, closed.
LOOP_WAYPOINTS = [(1.25, 1.25), (10.75, 1.25), (10.75, 8.75), (1.25, 8.75), (1.25, 1.25)]


def two_rooms() -> list:
    """Two identical 5 m x 4 m rooms, 10 m apart, joined by a 1 m wide corridor through doorways."""
    walls = []
    for x0 in (0.0, 10.0):
        x1 = x0 + 5.0
        walls += [((x0, 0.0), (x1, 0.0)), ((x0, 4.0), (x1, 4.0))]
        # West and east walls, each with a 1 m doorway at y 1.5..2.5 on the side facing the corridor.
        walls += [((x0, 0.0), (x0, 1.5)), ((x0, 2.5), (x0, 4.0))] if x0 > 0 else [((x0, 0.0), (x0, 4.0))]
        walls += [((x1, 0.0), (x1, 1.5)), ((x1, 2.5), (x1, 4.0))] if x0 == 0 else [((x1, 0.0), (x1, 4.0))]
    walls += [((5.0, 1.5), (10.0, 1.5)), ((5.0, 2.5), (10.0, 2.5))]
    return walls


ROOMS_WAYPOINTS = [(1.0, 2.0), (14.0, 2.0)]


def path(
    waypoints, laps: float = 1.0, step: float = 0.05, turn_step: float = math.radians(8.0)
) -> list[Pose]:
    """True poses along the waypoints (straight legs at ``step`` m per scan, turning in place at
    ``turn_step`` rad per scan at each corner), repeated for ``laps`` (fractions end mid-route)."""
    pts = list(waypoints)
    legs = [(pts[k], pts[k + 1]) for k in range(len(pts) - 1)]
    total = round(laps * len(legs))
    seq = [legs[k % len(legs)] for k in range(total)]
    poses: list[Pose] = []
    heading = math.atan2(seq[0][1][1] - seq[0][0][1], seq[0][1][0] - seq[0][0][0])
    for a, b in seq:
        want = math.atan2(b[1] - a[1], b[0] - a[0])
        while abs(math.remainder(want - heading, 2 * math.pi)) > 1e-9:
            d = math.remainder(want - heading, 2 * math.pi)
            heading += max(-turn_step, min(turn_step, d))
            poses.append((a[0], a[1], heading))
        n = max(1, int(math.hypot(b[0] - a[0], b[1] - a[1]) / step))
        for k in range(n):
            f = k / n
            poses.append((a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), heading))
    return poses


def drive_mapper(mapper, walls, truth: list[Pose], scale_error=0.01, heading_per_m=0.0017, dt=0.1):
    """Feed odometry (true increments with a scale error and a heading drift per metre, rad/m:
    0.0017 is 0.1°/m) and ray cast
    scans to ``mapper``. Returns (events, truth Track, odometry Track)."""
    events = []
    odo_track, truth_track = Track(), Track()
    for k, (pose, odo) in enumerate(zip(truth, drifting(truth, scale_error, heading_per_m), strict=True)):
        t = k * dt
        events += mapper.add_odometry(Odometry(t, *odo))
        events += mapper.add_scan(cast(walls, pose, n=181, max_range=30.0, t=t))
        odo_track.append(t, odo)
        truth_track.append(t, pose)
    return events, truth_track, odo_track


def write_carmen(path, walls, truth: list[Pose], odometry: list[Pose] | None = None, dt: float = 0.1) -> None:
    """A FLASER log of a run: ray cast scans (180 beams, 1°) at the true poses, logged with the
    ``odometry`` poses (the truth when None): a raw log, or with truth poses a "corrected" one."""
    lines = ["# synthetic run", "PARAM robot_frontlaser_offset 0.0 nohost 0"]
    for k, pose in enumerate(truth):
        scan = cast(walls, pose, n=180, max_range=30.0, t=k * dt)
        p = (odometry or truth)[k]
        ranges = " ".join(f"{r:.2f}" for r in scan.ranges)
        xyz = f"{p[0]:.4f} {p[1]:.4f} {p[2]:.5f}"
        lines.append(f"FLASER 180 {ranges} {xyz} {xyz} {k * dt:.3f} synth {k * dt:.3f}")
    path.write_text("\n".join(lines) + "\n")


def drifting(truth: list[Pose], scale_error=0.01, heading_per_m=0.0017) -> list[Pose]:
    """Odometry poses along a true path: its increments with a scale error and a heading drift (rad/m)."""
    odo = [truth[0]]
    for k in range(1, len(truth)):
        d = between(truth[k - 1], truth[k])
        dist = math.hypot(d[0], d[1])
        odo.append(compose(odo[-1], (d[0] * (1 + scale_error), d[1], d[2] + heading_per_m * dist)))
    return odo
