"""The controller's reading of a scan (robot frame: x forward, y left; m, rad): scan points, free
distance along each heading, the laser safety limit on speed; and the velocity :class:`Command`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.explore.params import ExploreParams


@dataclass(frozen=True, slots=True)
class Command:
    """A velocity command: ``v`` m/s forward, ``w`` rad/s counter-clockwise; ``status`` says why."""

    v: float
    w: float
    status: str
    done: bool = False


def scan_points(ranges: np.ndarray, angles: np.ndarray, max_range: float, p: ExploreParams) -> np.ndarray:
    """Returns of a scan (ranges m, angles rad in the laser frame) as points (N, 2) in the robot frame."""
    r = np.asarray(ranges, dtype=float)
    ok = np.isfinite(r) & (r > 0.02) & (r < max_range)
    a = np.asarray(angles, dtype=float)[ok]
    return np.column_stack([p.laser_x + r[ok] * np.cos(a), p.laser_y + r[ok] * np.sin(a)])


def free_distance(points: np.ndarray, headings: np.ndarray, p: ExploreParams, margin: float) -> np.ndarray:
    """For each heading (rad, robot frame): how far (m) the robot's front can travel straight along
    it before its body (half width + ``margin``) meets a scan point; ``inf`` when nothing is in the way."""
    if not len(points):
        return np.full(len(headings), np.inf)
    c, s = np.cos(headings)[:, None], np.sin(headings)[:, None]
    along = points[None, :, 0] * c + points[None, :, 1] * s
    lateral = -points[None, :, 0] * s + points[None, :, 1] * c
    blocking = (np.abs(lateral) < p.half_width + margin) & (along > 0.0)
    return np.where(blocking, along - p.front, np.inf).min(axis=1)


def safety_limit(points: np.ndarray, v: float, p: ExploreParams, margin: float | None = None) -> float:
    """The forward speed (m/s) allowed by the laser: 0 when a point in the robot's path (half width
    + ``margin`` m, default ``avoid_margin``, either side of its centreline, robot frame) is within
    ``stop_distance`` of the laser, ramping up over ``slow_zone`` beyond it. Reverse motion is not
    limited here (the laser cannot see behind)."""
    if v <= 0.0 or not len(points):
        return v
    margin = p.avoid_margin if margin is None else margin
    ahead = (np.abs(points[:, 1]) < p.half_width + margin) & (points[:, 0] > p.laser_x)
    if not ahead.any():
        return v
    gap = float((points[ahead, 0] - p.laser_x).min())
    return min(v, p.v_max * float(np.clip((gap - p.stop_distance) / p.slow_zone, 0.0, 1.0)))
