"""The emulated robot's body: P2OS motion setpoints, acceleration limits, true and odometry poses.

Pure state and arithmetic, no I/O: :class:`pioneer.emulator.PioneerEmulator` calls :meth:`step`
once per SIP cycle and reads the pose and wheel speeds to report. A different body (one replaying
the poses of a recorded log, say) only needs the same attributes and methods (:class:`Body`).

Frames and units: poses ``(x, y, theta)`` in metres and radians. The *true* pose is in the world
frame of whoever supplied ``start_pose``; the *odometry* pose is what the robot's encoders
integrate (with the :class:`OdometryError` model), starting at the same pose, as P2OS does.
Velocities in m/s and rad/s, accelerations in m/s² and rad/s².
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from pioneer.odometry import normalize_angle
from pioneer.params import P2DX, RobotParams

Pose = tuple[float, float, float]
# (old true pose, wished-for true pose) -> the pose the world allows, or None to block all motion.
MotionHook = Callable[[Pose, Pose], "Pose | None"]


@dataclass(frozen=True)
class OdometryError:
    """Systematic odometry error of the emulated robot.

    - ``distance_scale``: odometry distance = true distance × scale (wheel diameter error).
    - ``heading_scale``: odometry rotation = true rotation × scale (wheel base error).
    - ``drift_per_m``: rad of heading error accumulated per metre travelled (unequal wheels), signed.
    """

    distance_scale: float = 1.0
    heading_scale: float = 1.0
    drift_per_m: float = 0.0


class Body(Protocol):
    """What the emulator needs from a robot body (see :class:`DiffDrive` for the meaning)."""

    true_pose: Pose
    odometry_pose: Pose
    left_speed: float
    right_speed: float
    left_travel: float
    right_travel: float
    left_stall: bool
    right_stall: bool
    motors_enabled: bool
    max_v: float
    max_w: float
    accel: float
    decel: float
    rot_accel: float
    rot_decel: float
    heading_target: float | None

    def step(self, dt: float) -> None: ...
    def set_velocity(self, v: float) -> None: ...
    def set_rotation(self, w: float) -> None: ...
    def set_wheels(self, left: float, right: float) -> None: ...
    def set_heading(self, theta: float) -> None: ...
    def stop(self) -> None: ...
    def e_stop(self) -> None: ...
    def reset_odometry(self) -> None: ...


def advance(pose: Pose, ds: float, dth: float) -> Pose:
    """``pose`` moved ``ds`` metres along the mid-step heading and turned ``dth`` radians."""
    x, y, th = pose
    mid = th + dth / 2.0
    return (x + ds * math.cos(mid), y + ds * math.sin(mid), normalize_angle(th + dth))


def _toward(value: float, target: float, up: float, down: float, dt: float) -> float:
    """``value`` moved toward ``target`` at ``up`` when speeding up, ``down`` when slowing down."""
    rate = up if (target * value >= 0 and abs(target) > abs(value)) else down
    step = rate * dt
    if abs(target - value) <= step:
        return target
    return value + math.copysign(step, target - value)


class Setpoints:
    """The P2OS motion setpoints every body keeps, whether or not it acts on them.

    Translational ``v_cmd`` (VEL, m/s), rotational ``w_cmd`` (RVEL/ROTATE, rad/s) or a heading in
    the odometry frame (HEAD/DHEAD, rad); VEL2 sets both from wheel speeds. ``max_v``/``max_w``
    (SETV/SETRV) clamp them; ``accel``/``decel`` (m/s²) and ``rot_accel``/``rot_decel`` (rad/s²)
    are SETA/SETRA. Subclasses supply the poses and :meth:`step` (see :class:`Body`).
    """

    odometry_pose: Pose

    def __init__(self, params: RobotParams = P2DX) -> None:
        self.params = params
        self.v = self.w = 0.0
        self.v_cmd = self.w_cmd = 0.0
        self.heading_target: float | None = None
        self.max_v = params.max_velocity / 1000.0
        self.max_w = math.radians(params.max_rvelocity)
        self.accel = params.trans_accel / 1000.0
        self.decel = params.trans_decel / 1000.0
        self.rot_accel = math.radians(params.rot_accel)
        self.rot_decel = math.radians(params.rot_decel)
        self.motors_enabled = False

    def set_velocity(self, v: float) -> None:
        self.v_cmd = max(-self.max_v, min(self.max_v, v))

    def set_rotation(self, w: float) -> None:
        self.heading_target = None
        self.w_cmd = max(-self.max_w, min(self.max_w, w))

    def set_wheels(self, left: float, right: float) -> None:
        self.set_velocity((left + right) / 2.0)
        self.set_rotation((right - left) / self.params.wheel_base)

    def set_heading(self, theta: float) -> None:
        """Turn to ``theta`` (rad, odometry frame) and hold it."""
        self.heading_target = normalize_angle(theta)

    def stop(self) -> None:
        """STOP: zero setpoints, decelerate at the configured rates."""
        self.v_cmd = self.w_cmd = 0.0
        self.heading_target = None

    def e_stop(self) -> None:
        """E_STOP: zero setpoints and velocities at once (overrides deceleration)."""
        self.stop()
        self.v = self.w = 0.0

    def reset_odometry(self) -> None:
        """SETO: the odometry pose becomes (0, 0, 0); the true pose is unaffected."""
        self.odometry_pose = (0.0, 0.0, 0.0)
        if self.heading_target is not None:
            self.heading_target = None
            self.w_cmd = 0.0


class DiffDrive(Setpoints):
    """A differential-drive robot obeying P2OS motion commands (:class:`Setpoints`).

    The actual velocities ``v``, ``w`` approach the setpoints within the acceleration limits and the
    maxima. With the motors disabled the robot slows to a stop but keeps its setpoints: P2OS
    resumes them on ENABLE 1.
    """

    def __init__(
        self,
        params: RobotParams = P2DX,
        start_pose: Pose = (0.0, 0.0, 0.0),
        odometry_error: OdometryError | None = None,
        motion_hook: MotionHook | None = None,
    ) -> None:
        super().__init__(params)
        self.error = odometry_error or OdometryError()
        self.motion_hook = motion_hook
        self.true_pose: Pose = tuple(map(float, start_pose))  # type: ignore[assignment]
        self.odometry_pose: Pose = self.true_pose
        self.left_speed = self.right_speed = 0.0  # measured by the encoders, m/s
        self.left_stall = self.right_stall = False
        self.left_travel = self.right_travel = 0.0  # encoder-measured wheel travel, m
        self.distance = 0.0  # true distance travelled, m

    # --- motion ---------------------------------------------------------------------------------
    def _rotation_target(self, dt: float) -> float:
        if self.heading_target is None:
            return self.w_cmd
        err = normalize_angle(self.heading_target - self.odometry_pose[2])
        # Slow down early enough to stop on the heading (w² = 2·decel·err, err counted from where
        # this step at the present speed will leave the robot), and never turn past it in one step.
        ahead = max(0.0, abs(err) - abs(self.w) * dt)
        w = math.copysign(min(math.sqrt(2 * self.rot_decel * ahead), abs(err) / dt), err)
        return max(-self.max_w, min(self.max_w, w))

    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds: velocities toward their setpoints, then the poses."""
        if dt <= 0:
            return
        v_target, w_target = (self.v_cmd, self._rotation_target(dt)) if self.motors_enabled else (0.0, 0.0)
        self.v = _toward(self.v, v_target, self.accel, self.decel, dt)
        self.w = _toward(self.w, w_target, self.rot_accel, self.rot_decel, dt)
        old = self.true_pose
        ds, dth = self.v * dt, self.w * dt
        wished = advance(old, ds, dth)
        allowed = wished
        if self.motion_hook is not None and (ds or dth):
            allowed = self.motion_hook(old, wished) or old
        blocked = allowed != wished
        # Blocked wheels do not turn (the encoders see no motion) while the motors keep pushing.
        self.left_stall = self.right_stall = blocked
        # What the wheels actually did (the projection of the allowed motion on the mid heading).
        dth_true = normalize_angle(allowed[2] - old[2])
        mid = old[2] + dth_true / 2.0
        ds_true = (allowed[0] - old[0]) * math.cos(mid) + (allowed[1] - old[1]) * math.sin(mid)
        self.true_pose = (allowed[0], allowed[1], allowed[2])
        self.distance += abs(ds_true)
        e = self.error
        ds_odo = ds_true * e.distance_scale
        dth_odo = dth_true * e.heading_scale + e.drift_per_m * abs(ds_true)
        self.odometry_pose = advance(self.odometry_pose, ds_odo, dth_odo)
        half_base = self.params.wheel_base / 2.0
        self.left_speed = (ds_odo - dth_odo * half_base) / dt
        self.right_speed = (ds_odo + dth_odo * half_base) / dt
        self.left_travel += self.left_speed * dt
        self.right_travel += self.right_speed * dt

    @property
    def moving(self) -> bool:
        return bool(self.left_speed or self.right_speed)
