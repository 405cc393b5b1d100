"""How far a configured parameter may lie from its default (``[mapper]`` and ``[mapper.cycles]`` in
the service's config): beyond this a value is a typing mistake (a size in mm, an angle in degrees),
and some exhaust the robot's memory or divide by zero in the mapper thread."""

from __future__ import annotations

import math
from collections.abc import Mapping, Set
from typing import Any

#: A configured number lies within this factor of its default, either way.
LIMIT_FACTOR = 1000.0


def scaled_range(default: float, *, zero: bool = False, angle: bool = False) -> tuple[float, float]:
    """The closed range for a parameter whose default is ``default`` (> 0): ``default`` /
    :data:`LIMIT_FACTOR` (0 when ``zero`` is meaningful, as a margin or a radius of 0 is the
    paper's plain test) to ``default`` x :data:`LIMIT_FACTOR`, at most pi for an ``angle`` (rad);
    whole numbers from 1 (or 0) for an int default."""
    lo = 0.0 if zero else default / LIMIT_FACTOR
    hi = default * LIMIT_FACTOR
    if isinstance(default, int):
        lo, hi = (0 if zero else max(1, math.ceil(lo))), math.floor(hi)
    if angle:
        hi = min(hi, math.pi)
    return lo, hi


def field_range(defaults: Any, name: str, *, own: Mapping[str, tuple[float, float]],
                angles: Set[str], zero: bool = False) -> tuple[float, float]:
    """The range of field ``name`` of the parameters ``defaults``: its own when ``own`` names one,
    else :func:`scaled_range` of its default (``angle`` when ``angles`` holds it)."""
    if name in own:
        return own[name]
    return scaled_range(getattr(defaults, name), zero=zero, angle=name in angles)
