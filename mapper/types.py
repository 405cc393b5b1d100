"""The mapper's input readings and its map record, shared by every mapper module.

Frames: *odometry frame* (where :class:`Odometry` poses live, drifting), each *ASR frame* (the
robot pose at the scan that created that ASR), and the *global frame* (the global metric map, in
which each ASR frame has its ``origin``). Units: metres, radians, seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from mapper.se2 import Pose


@dataclass(frozen=True, slots=True)
class Odometry:
    """Wheel odometry: time ``t`` (s), ``x``, ``y`` (m), ``theta`` (rad), in the odometry frame."""

    t: float
    x: float
    y: float
    theta: float

    @property
    def pose(self) -> Pose:
        return (self.x, self.y, self.theta)


@dataclass(frozen=True, slots=True, eq=False)
class Scan:
    """One laser sweep in the laser frame (x forward, y left, counter-clockwise angles).

    ``t``: time (s) on the same clock as :class:`Odometry`; ``ranges``: float array (m), beam i at
    ``angle_min + i * angle_increment`` (rad); readings >= ``max_range`` (m) are *no return*.
    """

    t: float
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    max_range: float

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
