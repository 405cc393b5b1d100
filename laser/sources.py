"""Range sources for the emulator: callables ``ranges(t, angles) -> metres``.

``t`` is the emulator's ``time.monotonic()`` seconds at the scan's first ray (the instant the reader
dates it: the telegram's arrival minus its sweep and transmission times), ``angles`` the beam angles in
radians in the sensor frame (counter-clockwise, 0 = straight ahead). A source returns one range per
angle in metres; NaN or inf means "no return". Anything with that signature plugs in: a fixed
scan, a log player, a simulator's ray caster.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

RangeSource = Callable[[float, np.ndarray], np.ndarray]


def constant(metres: float = 2.0) -> RangeSource:
    """Every beam reads ``metres``."""

    def ranges(t: float, angles: np.ndarray) -> np.ndarray:
        return np.full(len(angles), metres)

    return ranges


def fixed(values) -> RangeSource:
    """Always the same scan (metres, one per beam; resampled by angle order if the count differs)."""
    base = np.asarray(values, dtype=np.float64)

    def ranges(t: float, angles: np.ndarray) -> np.ndarray:
        if len(angles) == len(base):
            return base
        idx = np.linspace(0, len(base) - 1, len(angles)).round().astype(int)
        return base[idx]

    return ranges


def room(
    width: float = 8.0,
    depth: float = 5.0,
    x: float = 2.0,
    y: float = 2.0,
    theta: float = 0.3,
    pillar: tuple[float, float, float] | None = (5.5, 3.0, 0.4),
) -> RangeSource:
    """A rectangular room [0, width] x [0, depth] (metres) seen from a sensor at (x, y, theta), with
    an optional round pillar (cx, cy, radius). Exact ray casting, vectorised over beams."""

    def ranges(t: float, angles: np.ndarray) -> np.ndarray:
        a = np.asarray(angles) + theta
        dx, dy = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(dx > 0, (width - x) / dx, np.where(dx < 0, -x / dx, np.inf))
            ty = np.where(dy > 0, (depth - y) / dy, np.where(dy < 0, -y / dy, np.inf))
        r = np.minimum(tx, ty)
        if pillar is not None:
            cx, cy, radius = pillar
            ox, oy = x - cx, y - cy
            b = ox * dx + oy * dy
            disc = b * b - (ox * ox + oy * oy - radius * radius)
            with np.errstate(invalid="ignore"):
                hit = -b - np.sqrt(disc)
            r = np.where((disc >= 0) & (hit > 0), np.minimum(r, hit), r)
        return r

    return ranges
