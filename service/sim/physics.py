"""The robot's body in the world: footprint collision checks and the ground-truth trajectory.

Poses: ``(x, y, theta)`` (m, m, rad). The *world frame* is the world file's; the pioneer emulator
integrates its own true pose from (0, 0, 0) at power-on, so world pose = ``world.start`` ⊕
emulator pose (:meth:`Body.world_pose`). Odometry error is the emulator's business, not this
module's: the body only ever sees true motion.

Footprints (spec p2os.md §1.10): ``"rect"`` is the Pioneer 2DX's 511 x 425 mm body, 210 mm in front
of the turning centre and 301 mm behind it; ``"circle"`` its 250 mm ``RobotRadius``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
import shapely

from mapper.se2 import Pose, compose, interpolate, inverse, transform_points
from service.sim.world import World

P2DX_FRONT, P2DX_REAR, P2DX_HALF_WIDTH, P2DX_RADIUS = 0.210, 0.301, 0.2125, 0.250


def footprint_outline(kind: str = "rect") -> np.ndarray:
    """The footprint's outline (K, 2) in the robot frame (m): ``"rect"`` or ``"circle"``."""
    if kind == "rect":
        return np.array([[P2DX_FRONT, -P2DX_HALF_WIDTH], [P2DX_FRONT, P2DX_HALF_WIDTH],
                         [-P2DX_REAR, P2DX_HALF_WIDTH], [-P2DX_REAR, -P2DX_HALF_WIDTH]])
    if kind == "circle":
        a = np.linspace(0.0, 2.0 * math.pi, 32, endpoint=False)
        return P2DX_RADIUS * np.column_stack([np.cos(a), np.sin(a)])
    raise ValueError(f"footprint must be 'rect' or 'circle', not {kind!r}")


@dataclass
class Contact:
    """A blocked motion: ``t`` (s, the caller's clock), the pose the body stopped at, where it was going."""

    t: float
    pose: Pose
    wanted: Pose


class Body:
    """The robot's true pose in ``world`` and a collision check for every motion.

    :meth:`move` is the motion hook: the body goes where it is told unless its footprint (plus
    ``margin`` m) would meet an obstacle; then it stops at the last free pose found by bisection
    along the motion and the move reports a stall. ``trajectory`` keeps (t, world pose) samples
    every ``record_every`` m or rad of motion for ground truth; ``distance`` is the metres driven.
    Thread-safe: the emulator moves the body while the simulator reads it.
    """

    def __init__(self, world: World, *, footprint: str = "rect", margin: float = 0.0,
                 pose: Pose | None = None, record_every: float = 0.02) -> None:
        self.world = world
        self.outline = footprint_outline(footprint)
        if margin > 0.0:
            grown = shapely.Polygon(self.outline).buffer(margin, join_style="mitre")
            self.outline = np.asarray(grown.exterior.coords)[:-1]
        self.pose: Pose = tuple(float(v) for v in (pose or world.start))  # type: ignore[assignment]
        self.origin: Pose = world.start
        self.distance = 0.0
        self.rotation = 0.0
        self.contacts: list[Contact] = []
        self.trajectory: list[tuple[float, Pose]] = [(0.0, self.pose)]
        self.record_every = record_every
        self._lock = threading.Lock()
        if self.collides(self.pose):
            raise ValueError(f"{world.source or world.name}: the robot at {self.pose} overlaps an obstacle")

    def polygon(self, pose: Pose) -> shapely.Polygon:
        """The footprint at ``pose`` (world frame) as a shapely polygon."""
        return shapely.Polygon(transform_points(pose, self.outline))

    def collides(self, pose: Pose) -> bool:
        """True if the footprint at ``pose`` (world frame) touches any obstacle."""
        return bool(self.world.obstacles.intersects(self.polygon(pose)))

    def world_pose(self, emulator_pose: Pose) -> Pose:
        """An emulator pose (its frame starts at (0, 0, 0) at the world's start pose) in the world frame."""
        return compose(self.origin, emulator_pose)

    def emulator_pose(self, world_pose: Pose) -> Pose:
        """The inverse of :meth:`world_pose`."""
        return compose(inverse(self.origin), world_pose)

    def move(self, new: Pose, t: float = math.nan) -> tuple[Pose, bool]:
        """Try to go from the current pose to ``new`` (world frame) in a straight interpolation.

        Returns (the pose reached, stalled). Intermediate poses are checked too, every 5 cm or
        0.1 rad, so a large step cannot jump through a thin wall.
        """
        with self._lock:
            old = self.pose
            step = max(math.hypot(new[0] - old[0], new[1] - old[1]) / 0.05,
                       abs(math.remainder(new[2] - old[2], 2.0 * math.pi)) / 0.1)
            n = max(1, math.ceil(step))
            reached, stalled = old, False
            for i in range(1, n + 1):
                cand = interpolate(old, new, i / n)
                if self.collides(cand):
                    reached = self._contact(reached, cand)
                    stalled = True
                    break
                reached = cand
            self._advance(old, reached, t)
            if stalled:
                self.contacts.append(Contact(t, reached, new))
            return reached, stalled

    def _contact(self, free: Pose, blocked: Pose, iterations: int = 6) -> Pose:
        """The last free pose between ``free`` and ``blocked`` (bisection, ~1 mm after 6 halvings of 5 cm)."""
        for _ in range(iterations):
            mid = interpolate(free, blocked, 0.5)
            if self.collides(mid):
                blocked = mid
            else:
                free = mid
        return free

    def _advance(self, old: Pose, new: Pose, t: float) -> None:
        self.distance += math.hypot(new[0] - old[0], new[1] - old[1])
        self.rotation += abs(math.remainder(new[2] - old[2], 2.0 * math.pi))
        self.pose = new
        last = self.trajectory[-1][1]
        if (math.hypot(new[0] - last[0], new[1] - last[1]) >= self.record_every
                or abs(math.remainder(new[2] - last[2], 2.0 * math.pi)) >= self.record_every):
            self.trajectory.append((t, new))

    def pose_at(self, t: float) -> Pose:
        """The true pose (world frame) at time ``t`` from the recorded trajectory (the current pose if
        ``t`` is past its end)."""
        with self._lock:
            traj = list(self.trajectory)
            current = self.pose
        times = [s[0] for s in traj]
        if not traj or t >= times[-1] or not all(math.isfinite(x) for x in times[-2:]):
            return current
        k = int(np.searchsorted(times, t))
        if k == 0:
            return traj[0][1]
        (t0, p0), (t1, p1) = traj[k - 1], traj[k]
        return interpolate(p0, p1, (t - t0) / (t1 - t0) if t1 > t0 else 1.0)
