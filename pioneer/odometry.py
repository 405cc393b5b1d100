"""SIPs into a continuous pose in the odometry frame (spec §1.7, §1.8).

The odometry frame's origin is the robot's pose at the first SIP after connecting: x forward,
y left, theta counter-clockwise (REP-103). Metres, radians, seconds.

P2OS integrates its own position and sends the 15 low bits of it, so the increment between two SIPs
is ``Δ = ((new - old + 0x4000) & 0x7FFF) - 0x4000`` units (any jump under ±16384 units, ±13.8 m at
0.84 mm/unit, is taken the short way) × DistConvFactor. The heading is absolute
(THPOS × 2π/4096); it is unwrapped so that the increments are continuous, and reported in (-π, π].
Increments are in the robot's internal frame; they are rotated by the constant angle between that
frame and ours (set at the first SIP of each session), which is exact because P2OS did the
integration with its own heading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pioneer.params import P2DX, RobotParams
from pioneer.sip import SIP


def wrap15(delta: int) -> int:
    """The signed difference of two 15-bit positions, in (-0x4000, 0x4000]."""
    return ((delta + 0x4000) & 0x7FFF) - 0x4000


def normalize_angle(a: float) -> float:
    """``a`` (rad) in (-π, π]."""
    a = math.fmod(a, 2 * math.pi)
    if a > math.pi:
        a -= 2 * math.pi
    elif a <= -math.pi:
        a += 2 * math.pi
    return a


@dataclass(frozen=True)
class PioneerOdometry:
    """One SIP as odometry. ``t``: host ``time.monotonic()`` (s) when the SIP's first byte left the
    robot (its arrival minus its transfer time at the baud); strictly increasing.
    ``x``, ``y`` (m), ``theta`` (rad, in (-π, π]): pose in the odometry frame. ``v`` (m/s), ``w``
    (rad/s): the robot's velocities; ``left``, ``right`` (m/s): wheel speeds. ``sip``: the packet."""

    t: float
    x: float
    y: float
    theta: float
    v: float
    w: float
    left: float
    right: float
    sip: SIP

    @property
    def battery(self) -> float:
        """Battery voltage, volts."""
        return self.sip.battery_volts

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)


class OdometryIntegrator:
    """Accumulates SIP positions across the 15-bit wraparound (pure; one per driver).

    :meth:`rebase` starts a new robot session (after a reconnect P2OS may have been reset): the next
    SIP becomes the new reference and the pose continues from where it was, so the odometry frame
    stays continuous for the caller. What the robot did while the link was down is not seen.
    """

    def __init__(self, params: RobotParams = P2DX) -> None:
        self.params = params
        self._ref: tuple[int, int, int] | None = None  # last raw (x, y, th)
        self._x = self._y = 0.0  # metres, odometry frame
        self._heading = 0.0  # unwrapped, rad, odometry frame
        self._cos = 1.0  # rotation robot frame -> odometry frame
        self._sin = 0.0
        self._turn = round(2 * math.pi / params.angle_conv)  # THPOS units per revolution (4096)

    def rebase(self) -> None:
        self._ref = None

    def reset(self) -> None:
        """Back to the origin (after SETO, or to define a new odometry frame)."""
        self._ref = None
        self._x = self._y = self._heading = 0.0

    def update(self, sip: SIP, t: float) -> PioneerOdometry:
        p = self.params
        if self._ref is None:
            rot = self._heading - sip.thpos * p.angle_conv
            self._cos, self._sin = math.cos(rot), math.sin(rot)
        else:
            x0, y0, th0 = self._ref
            dx = wrap15(sip.xpos - x0) * p.dist_conv / 1000.0
            dy = wrap15(sip.ypos - y0) * p.dist_conv / 1000.0
            self._x += self._cos * dx - self._sin * dy
            self._y += self._sin * dx + self._cos * dy
            # THPOS is in 4096ths of a turn and wraps at ±2048, so its differences wrap modulo a turn.
            half = self._turn // 2
            self._heading += (((sip.thpos - th0 + half) % self._turn) - half) * p.angle_conv
        self._ref = (sip.xpos, sip.ypos, sip.thpos)
        left = sip.left_vel * p.vel_conv / 1000.0
        right = sip.right_vel * p.vel_conv / 1000.0
        if sip.rot_vel is not None:
            w = math.radians(sip.rot_vel / 10.0)
        else:
            w = (sip.right_vel - sip.left_vel) * p.vel_conv / 2.0 * p.diff_conv
        # Built like decode_sip builds a SIP (one dict display): this runs for every SIP.
        odo = object.__new__(PioneerOdometry)
        object.__setattr__(odo, "__dict__", {
            "t": t, "x": self._x, "y": self._y, "theta": normalize_angle(self._heading),
            "v": (left + right) / 2.0, "w": w, "left": left, "right": right, "sip": sip,
        })
        return odo
