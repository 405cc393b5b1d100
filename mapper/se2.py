"""SE(2) poses as ``(x, y, theta)``: metres and radians, theta wrapped to (-pi, pi].

``compose(a, b)`` is a ⊕ b: the pose b (given in a's frame) expressed in the frame a is given in.
``between(a, b)`` is a⁻¹ ⊕ b: b seen from a. Vectorised forms take arrays of shape (N, 3).
"""

from __future__ import annotations

import math

import numpy as np

Pose = tuple[float, float, float]


def wrap(theta: float) -> float:
    """Angle in radians wrapped to (-pi, pi]."""
    t = math.fmod(theta + math.pi, 2.0 * math.pi)
    if t <= 0.0:
        t += 2.0 * math.pi
    return t - math.pi


def wrap_array(theta: np.ndarray) -> np.ndarray:
    """Vectorised :func:`wrap` (radians)."""
    return np.pi - np.mod(np.pi - np.asarray(theta, dtype=float), 2.0 * np.pi)


def compose(a: Pose, b: Pose) -> Pose:
    """a ⊕ b: pose b, expressed in frame a, brought into the frame a is expressed in."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def inverse(a: Pose) -> Pose:
    """a⁻¹: the frame that a is expressed in, seen from a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap(-a[2]))


def between(a: Pose, b: Pose) -> Pose:
    """a⁻¹ ⊕ b: pose b seen from pose a (both in the same frame)."""
    return compose(inverse(a), b)


def transform_points(pose: Pose, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) given in the frame ``pose`` into the frame pose is expressed in (metres)."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty_like(pts)
    out[:, 0] = pose[0] + c * pts[:, 0] - s * pts[:, 1]
    out[:, 1] = pose[1] + s * pts[:, 0] + c * pts[:, 1]
    return out


def interpolate(a: Pose, b: Pose, f: float) -> Pose:
    """Pose a fraction f (0..1) of the way from a to b, along the shortest turn (radians)."""
    return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), wrap(a[2] + f * wrap(b[2] - a[2])))
