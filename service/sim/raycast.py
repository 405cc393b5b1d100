"""Ray casting in a :class:`~service.sim.world.World`: what a laser scanner at a pose reads.

All beams against all segments and circles at once (numpy broadcasting, no Python loop per beam).
Segments farther from the laser than the max range are culled first, which keeps the (beams x
segments) arrays small in worlds larger than the scanner's reach.

Frames: the robot pose is in the world frame (m, m, rad); beam angles are in the laser frame
(counter-clockwise, 0 = straight ahead); the laser sits at ``mount`` (x, y, theta) in the robot
frame (Pioneer 2DX: x = 0.017 m, y = 0.008 m, spec p2os.md §1.10).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from mapper.se2 import Pose, compose
from service.sim.world import World

# Above this many (beam, segment) pairs, testing each segment only against the beams inside the angle
# it subtends beats broadcasting all against all (measured: the crossover is near 40 segments x 181 beams).
_BROADCAST_MAX = 8000
LMS_MAX_RANGE = 8.191  # m: the LMS200's largest code in mm mode; anything beyond reads as no return
P2DX_LASER_MOUNT: Pose = (0.017, 0.008, 0.0)


def cast(origin: tuple[float, float], directions: np.ndarray, segments: np.ndarray,
         circles: np.ndarray, max_range: float = math.inf) -> np.ndarray:
    """Distance (m) along each ray from ``origin`` to the first segment or circle it meets.

    ``directions``: beam angles (rad) in the world frame, shape (B,), increasing (as in a scan).
    ``segments``: (S, 4) ``x1, y1, x2, y2``; ``circles``: (C, 3) ``x, y, r`` (world frame, m). Rays
    that meet nothing within ``max_range`` get ``inf``. A ray starting inside a circle reads the
    distance to its far side (the sensor is never inside an obstacle in a valid simulation).

    Beyond a few thousand (beam, segment) pairs, each primitive is tested only against the beams
    inside the angle it subtends from the origin (found by ``searchsorted``), so the work grows with
    the number of pairs that can actually meet, not with beams x primitives.
    """
    ox, oy = origin
    directions = np.asarray(directions, dtype=float)
    best = np.full(directions.shape, np.inf)
    if not len(directions):
        return best
    beta = directions - directions[0]
    if len(beta) > 1 and not np.all(np.diff(beta) > 0.0):
        raise ValueError("cast: beam directions must be strictly increasing")
    if len(segments):
        segs = segments[_within(segments, ox, oy, max_range)]
        if len(segs):
            px, py = segs[:, 0] - ox, segs[:, 1] - oy
            ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
            if len(segs) * len(directions) <= _BROADCAST_MAX:
                # Few primitives: every beam against every segment costs less than finding pairs.
                bi = si = slice(None)
                dx, dy = np.cos(directions)[:, None], np.sin(directions)[:, None]
            else:
                a1 = np.arctan2(py, px)
                w = _wrap(np.arctan2(py + ey, px + ex) - a1)
                start = np.where(w < 0.0, a1 + w, a1)
                bi, si = _pairs(beta, start - directions[0], np.abs(w))
                dx, dy = np.cos(directions[bi]), np.sin(directions[bi])
            qx, qy, fx, fy = px[si], py[si], ex[si], ey[si]
            # Ray o + t d meets p + u e where t = (p x e) / (d x e), u = (p x d) / (d x e).
            denom = dx * fy - dy * fx
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (qx * fy - qy * fx) / denom
                u = (qx * dy - qy * dx) / denom
            t = np.where((denom != 0.0) & (t > 0.0) & (u >= -1e-9) & (u <= 1.0 + 1e-9), t, np.inf)
            if isinstance(bi, slice):
                best = np.minimum(best, t.min(axis=1))
            elif len(bi):
                np.minimum.at(best, bi, t)
    if len(circles):
        cx, cy, r = circles[:, 0] - ox, circles[:, 1] - oy, circles[:, 2]
        d = np.hypot(cx, cy)
        near = d - r <= max_range
        cx, cy, r, d = cx[near], cy[near], r[near], d[near]
        if len(d):
            half = np.where(d > r, np.arcsin(np.minimum(1.0, r / np.maximum(d, 1e-12))), np.pi)
            bi, ci = _pairs(beta, np.arctan2(cy, cx) - half - directions[0], 2.0 * half)
            if len(bi):
                dx, dy = np.cos(directions[bi]), np.sin(directions[bi])
                b = -(dx * cx[ci] + dy * cy[ci])  # (o - c) . d
                disc = b * b - (d[ci] ** 2 - r[ci] ** 2)
                root = np.sqrt(np.maximum(disc, 0.0))
                t = np.where(-b - root > 0.0, -b - root, -b + root)
                np.minimum.at(best, bi, np.where((disc >= 0.0) & (t > 0.0), t, np.inf))
    best[best > max_range] = np.inf
    return best


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _pairs(beta: np.ndarray, start: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(beam, primitive) index pairs with beam angle ``beta`` (rad from the first beam, increasing)
    inside the primitive's interval [start, start + width] (rad, same origin), modulo 2 pi."""
    eps = 1e-9
    s = np.mod(start - eps, 2.0 * np.pi)
    e = s + width + 2.0 * eps
    los, his = [], []
    # An interval that wraps past 2 pi is also the interval shifted down by one turn.
    for shift in (0.0, -2.0 * np.pi):
        los.append(np.searchsorted(beta, s + shift, side="left"))
        his.append(np.searchsorted(beta, e + shift, side="right"))
    lo = np.concatenate(los)
    hi = np.concatenate(his)
    prim = np.tile(np.arange(len(s)), 2)
    n = np.maximum(hi - lo, 0)
    total = int(n.sum())
    if total == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    owner = np.repeat(np.arange(len(n)), n)
    offsets = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    return lo[owner] + offsets, prim[owner]


def _within(segments: np.ndarray, ox: float, oy: float, reach: float) -> np.ndarray:
    """Mask of segments whose nearest point is within ``reach`` (m) of (ox, oy)."""
    if not math.isfinite(reach):
        return np.ones(len(segments), dtype=bool)
    ax, ay = segments[:, 0] - ox, segments[:, 1] - oy
    ex, ey = segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]
    f = np.clip(-(ax * ex + ay * ey) / np.maximum(ex * ex + ey * ey, 1e-18), 0.0, 1.0)
    return np.hypot(ax + f * ex, ay + f * ey) <= reach


class RayCaster:
    """A simulated LMS2xx in ``world``: :meth:`scan` gives the ranges (m) at a robot pose.

    ``sigma``: standard deviation (m) of the Gaussian range noise. ``max_range`` (m): beams that
    meet nothing within it read exactly ``max_range``, the scanner's no-return value. ``mount``:
    the laser's pose in the robot frame. ``seed`` makes the noise repeatable.
    """

    def __init__(self, world: World, *, sigma: float = 0.01, max_range: float = LMS_MAX_RANGE,
                 mount: Pose = P2DX_LASER_MOUNT, seed: int | None = 0) -> None:
        self.world = world
        self.sigma = float(sigma)
        self.max_range = float(max_range)
        self.mount = mount
        self._rng = np.random.default_rng(seed)

    def laser_pose(self, robot: Pose) -> Pose:
        """The laser's pose in the world frame for the robot pose ``robot`` (world frame)."""
        return compose(robot, self.mount)

    def scan(self, robot: Pose, angles: np.ndarray) -> np.ndarray:
        """Ranges (m) for beams at ``angles`` (rad, laser frame) with the robot at ``robot`` (world)."""
        lx, ly, lth = self.laser_pose(robot)
        r = cast((lx, ly), np.asarray(angles, dtype=float) + lth, self.world.segments,
                 self.world.circles, self.max_range)
        hit = np.isfinite(r)
        if self.sigma > 0.0:
            r[hit] += self._rng.normal(0.0, self.sigma, int(hit.sum()))
        # Noise cannot push a return past the no-return code or below the sensor's zero.
        r[hit] = np.clip(r[hit], 0.0, np.nextafter(self.max_range, 0.0))
        r[~hit] = self.max_range
        return r

    def source(self, robot_pose: Callable[[float], Pose]) -> Callable[[float, np.ndarray], np.ndarray]:
        """A range source ``ranges(t, angles) -> metres`` for :class:`laser.emulator.LMS2xxEmulator`:
        ``robot_pose(t)`` gives the true robot pose (world frame) at the emulator's time ``t``.

        A beam that meets nothing within ``max_range`` is ``inf`` (no return), which the emulator
        sends as the no-return code of the measuring mode the host configured. Sent as
        ``max_range`` itself it would be a real reading in any mode reaching further (the drivers
        set mode 5, 32 m): a phantom wall ``max_range`` away on every empty beam."""

        def ranges(t: float, angles: np.ndarray) -> np.ndarray:
            r = self.scan(robot_pose(t), angles)
            r[r >= self.max_range] = np.inf
            return r

        return ranges
