"""A robot body that plays back recorded odometry (a :class:`pioneer.physics.Body` for the emulator).

:class:`PlaybackBody` plugs into :class:`pioneer.emulator.PioneerEmulator` as its ``body``: at every
SIP cycle the emulator steps it and encodes its pose as a real P2OS would (0.84 mm and 2π/4096
units, x and y wrapped at 15 bits, wheel velocities in mm/s), so a recorded run reaches a driver
exactly as the robot sent it, quantisation included.

The recording is given as arrays (``t`` s, ``x``, ``y`` m, ``theta`` rad: the log's odometry frame);
this package reads no log files. Between samples the pose is interpolated linearly (theta along the
shorter turn); before the first sample and after the last it is held. Which time to show is asked
of ``clock()`` (seconds on the recording's own time axis) at every step, so one clock can drive this
body and a laser playing back the same recording and keep them in step at any speed factor.

Motion commands are accepted and remembered (a client sees the usual setpoint/STOP/ENABLE
behaviour, and ``stop()``/CLOSE leave the motors stopped) but do not move a recorded robot.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pioneer.odometry import normalize_angle
from pioneer.params import P2DX, RobotParams
from pioneer.physics import Pose, Setpoints

_MAX_WHEEL = 32.0  # m/s: below the int16 mm/s of a SIP's wheel velocity fields


class PoseTrack:
    """Poses ``(x, y, theta)`` (m, rad) at strictly increasing times ``t`` (s), interpolated.

    Samples whose time does not increase (duplicated or reordered log lines) are dropped, keeping
    the first. :meth:`at` is linear in x, y and in the unwrapped heading; held outside the span.
    """

    def __init__(self, t, x, y, theta) -> None:
        t = np.asarray(t, dtype=np.float64)
        keep = np.ones(len(t), dtype=bool)
        if len(t):
            # A running maximum keeps the first of every run of non-increasing times.
            prev = np.maximum.accumulate(t)
            keep[1:] = t[1:] > prev[:-1]
        if not keep.any():
            raise ValueError("a pose track needs at least one sample")
        self.t = t[keep]
        self.x = np.asarray(x, dtype=np.float64)[keep]
        self.y = np.asarray(y, dtype=np.float64)[keep]
        self.theta = np.unwrap(np.asarray(theta, dtype=np.float64)[keep])

    def __len__(self) -> int:
        return len(self.t)

    @property
    def start(self) -> float:
        return float(self.t[0])

    @property
    def end(self) -> float:
        return float(self.t[-1])

    def at(self, t: float) -> Pose:
        """The pose at time ``t`` (s), theta in (-π, π]."""
        ts = self.t
        x = float(np.interp(t, ts, self.x))
        y = float(np.interp(t, ts, self.y))
        th = float(np.interp(t, ts, self.theta))
        return (x, y, normalize_angle(th))

    def velocity(self, t: float) -> tuple[float, float]:
        """``(v, w)``: forward speed (m/s, signed along the heading) and turn rate (rad/s) at ``t``
        on the segment holding it (0, 0 outside the span)."""
        ts = self.t
        if len(ts) < 2 or t < ts[0] or t >= ts[-1]:
            return 0.0, 0.0
        i = int(np.searchsorted(ts, t, side="right"))
        dt = ts[i] - ts[i - 1]
        dx, dy = self.x[i] - self.x[i - 1], self.y[i] - self.y[i - 1]
        dth = self.theta[i] - self.theta[i - 1]
        mid = self.theta[i - 1] + dth / 2.0
        return (dx * math.cos(mid) + dy * math.sin(mid)) / dt, dth / dt


class PlaybackBody(Setpoints):
    """The :class:`pioneer.physics.Body` of a recorded robot: its odometry pose is ``track`` at
    ``clock()`` (module docstring). ``true_pose`` is the same pose (a log has no other truth here).

    Wheel speeds (m/s) follow the recorded motion: ``v ∓ w·base/2`` with the P2DX wheel base,
    as P2OS derives them from its encoders, so SIP wheel velocities are what the robot would send.
    """

    def __init__(self, track: PoseTrack, clock: Callable[[], float], params: RobotParams = P2DX) -> None:
        super().__init__(params)
        self.track = track
        self.clock = clock
        self.odometry_pose: Pose = track.at(track.start)
        self.true_pose: Pose = self.odometry_pose
        self.left_speed = self.right_speed = 0.0
        self.left_travel = self.right_travel = 0.0
        self.left_stall = self.right_stall = False
        self._offset: Pose | None = None  # SETO: the pose that became (0, 0, 0)

    # --- what the emulator calls once per SIP cycle ---------------------------------------------
    def step(self, dt: float) -> None:
        """Show the recording at ``clock()``; ``dt`` (wall seconds) only integrates wheel travel."""
        t = self.clock()
        pose = self.track.at(t)
        v, w = self.track.velocity(t)
        half = self.params.wheel_base / 2.0
        # A SIP carries int16 mm/s: a jump in a log (a relocalisation, a glitch) must not overflow it.
        self.left_speed = max(-_MAX_WHEEL, min(_MAX_WHEEL, v - w * half))
        self.right_speed = max(-_MAX_WHEEL, min(_MAX_WHEEL, v + w * half))
        if dt > 0:
            self.left_travel += self.left_speed * dt
            self.right_travel += self.right_speed * dt
        self.true_pose = pose
        self.odometry_pose = pose if self._offset is None else _relative(self._offset, pose)

    # --- commands: the Setpoints base remembers them; a recording never acts on them ---------
    def reset_odometry(self) -> None:
        self._offset = self.true_pose
        self.odometry_pose = (0.0, 0.0, 0.0)

    @property
    def commanded(self) -> tuple[float, float]:
        """The (v m/s, w rad/s) setpoints clients sent; (0, 0) once stopped."""
        return self.v_cmd, self.w_cmd


def _relative(origin: Pose, pose: Pose) -> Pose:
    """``pose`` in the frame of ``origin`` (both m, rad)."""
    dx, dy = pose[0] - origin[0], pose[1] - origin[1]
    c, s = math.cos(origin[2]), math.sin(origin[2])
    return (c * dx + s * dy, -s * dx + c * dy, normalize_angle(pose[2] - origin[2]))
