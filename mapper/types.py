"""The mapper's input readings and its map record, shared by every mapper module.

Frames: *odometry frame* (where :class:`Odometry` poses live, drifting), each *ASR frame* (the
robot pose at the scan that created that ASR), and the *global frame* (the global metric map, in
which each ASR frame has its ``origin``). Units: metres, radians, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely

from mapper.se2 import Pose

#: rad. The finest beam spacing a scan may have (an LMS200 at 0.25° has 4.4e-3 rad): closer beams are
#: a corrupt header, not a laser, and would make every beam the same ray.
MIN_BEAM_SPACING = 1e-4


#: The largest magnitude a pose coordinate (m), heading (rad), beam angle (rad) or range (m) may have:
#: 1000 km, a thousand turns. Beyond them a reading is corrupt, and the geometry would lose its
#: millimetres to rounding or overflow.
MAX_COORDINATE = 1e6
MAX_ANGLE = 2000 * math.pi


def _finite(owner: str, bound: float = math.inf, **values: float) -> None:
    for name, v in values.items():
        if not (math.isfinite(v) and abs(v) <= bound):
            raise ValueError(f"{owner}.{name} is {v!r}: expected a finite number"
                             + (f" of magnitude at most {bound:g}" if math.isfinite(bound) else ""))


@dataclass(frozen=True, slots=True)
class Odometry:
    """Wheel odometry: time ``t`` (s), ``x``, ``y`` (m), ``theta`` (rad), in the odometry frame.

    Raises ValueError on a NaN, infinite or absurd (:data:`MAX_COORDINATE`, :data:`MAX_ANGLE`) field:
    one would poison every pose after it."""

    t: float
    x: float
    y: float
    theta: float

    def __post_init__(self) -> None:
        _finite("Odometry", t=self.t)
        _finite("Odometry", MAX_COORDINATE, x=self.x, y=self.y)
        _finite("Odometry", MAX_ANGLE, theta=self.theta)

    @property
    def pose(self) -> Pose:
        return (self.x, self.y, self.theta)


@dataclass(frozen=True, slots=True, eq=False)
class Scan:
    """One laser sweep in the laser frame (x forward, y left, counter-clockwise angles).

    ``t``: time (s) on the same clock as :class:`Odometry`; ``ranges``: float array (m), beam i at
    ``angle_min + i * angle_increment`` (rad); readings >= ``max_range`` (m) are *no return*, and so
    are NaN or infinite readings.

    Raises ValueError when the sweep itself is not one: a non-finite time, angle or max range, ranges
    that are not one row, or beams closer than :data:`MIN_BEAM_SPACING` or spread over more than a
    full turn.
    """

    t: float
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    max_range: float

    def __post_init__(self) -> None:
        _finite("Scan", t=self.t)
        _finite("Scan", MAX_ANGLE, angle_min=self.angle_min, angle_increment=self.angle_increment)
        _finite("Scan", MAX_COORDINATE, max_range=self.max_range)
        n = int(np.size(self.ranges))
        if np.ndim(self.ranges) != 1:
            raise ValueError(f"Scan.ranges has shape {np.shape(self.ranges)}: expected one row of ranges (m)")
        if self.max_range <= 0:
            raise ValueError(f"Scan.max_range is {self.max_range!r}: expected a range > 0 (m)")
        spread = abs(self.angle_increment) * max(n - 1, 0)
        if n > 1 and not (abs(self.angle_increment) >= MIN_BEAM_SPACING and spread <= 2 * math.pi + 1e-6):
            raise ValueError(f"Scan.angle_increment is {self.angle_increment!r} rad for {n} beams: expected "
                             f"beams at least {MIN_BEAM_SPACING} rad apart within one turn")

    @property
    def angles(self) -> np.ndarray:
        """Beam angles (rad) in the laser frame."""
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


EDGE_LABELS = ("surface", "exit", "unknown")


@dataclass(slots=True)
class Exit:
    """A gap wide enough to pass, from ``a`` to ``b`` (m) in its ASR's frame.

    ``id`` is ``"<asr>/<n>"``; ``to`` is the ASR it leads to once crossed (None: unexplored).
    """

    id: str
    a: tuple[float, float]
    b: tuple[float, float]
    to: int | None = None

    @property
    def width(self) -> float:
        return float(np.hypot(self.b[0] - self.a[0], self.b[1] - self.a[1]))

    @property
    def midpoint(self) -> tuple[float, float]:
        return ((self.a[0] + self.b[0]) / 2.0, (self.a[1] + self.b[1]) / 2.0)


@dataclass(slots=True)
class ASR:
    """An absolute space representation: one local space in its own frame.

    ``created``: time (s) of the scan that created it; its frame is the robot pose at that scan.
    ``origin``: that frame's pose in the global metric map (m, m, rad). ``boundary``: (N, 2)
    polygon vertices in the ASR frame (m), counter-clockwise, not closed; ``edges[i]`` labels the
    edge boundary[i] -> boundary[i+1] (``surface``, ``exit`` or ``unknown``). ``centre`` (m, ASR
    frame) and ``centre_rule`` (``"centroid"`` or ``"point_on_surface"``). ``duplicate_of``: the
    ASR this one duplicates after a cycle closed on it. ``scans``: scans that built it.
    """

    id: int
    created: float
    origin: Pose
    boundary: np.ndarray
    edges: list[str]
    centre: tuple[float, float]
    centre_rule: str = "centroid"
    exits: list[Exit] = field(default_factory=list)
    duplicate_of: int | None = None
    scans: int = 0

    @property
    def polygon(self) -> shapely.Polygon:
        """The boundary as a shapely polygon in the ASR frame."""
        return shapely.Polygon(self.boundary)

    @property
    def area(self) -> float:
        """Area of the polygon (m²)."""
        return float(self.polygon.area)
