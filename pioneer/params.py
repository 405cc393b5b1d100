"""Robot parameters: the Pioneer 2DX values of ARIA ``params/p2dx.p`` and ROS-p2os (spec §1.10).

Conversion factors keep their P2OS names and units (mm per unit, rad per unit) because that is how
every published parameter file states them; the SI limits the driver works in are derived below.
Override any of them with :func:`dataclasses.replace`, e.g. ``replace(P2DX, max_velocity=500)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class RobotParams:
    """One robot model's P2OS parameters.

    - ``angle_conv``: rad per THPOS unit (2π/4096). ``dist_conv``: mm per XPOS/YPOS unit.
    - ``vel_conv``: mm/s per wheel velocity unit. ``range_conv``: mm per sonar range unit.
    - ``diff_conv``: rotational velocity (rad/s) = (R - L) / 2 × diff_conv, wheel speeds in mm/s;
      the effective wheel base is 2 / diff_conv mm (357 mm on a P2DX; derived, not published).
    - ``vel2_divisor``: mm/s per VEL2 wheel unit.
    - ``max_velocity`` (mm/s), ``max_rvelocity`` (deg/s): absolute limits of VEL/RVEL.
    - ``trans_accel``/``trans_decel`` (mm/s²), ``rot_accel``/``rot_decel`` (deg/s²): the FLASH
      defaults an emulated robot starts with (P2OS defaults; ARIA's p2dx.p says 0 = use FLASH).
    - ``sonar_poses``: (x mm, y mm, heading deg) of each transducer in the robot frame (ARIA p2dx.p).
    - ``sip_cycle``, ``watchdog``: seconds between SIPs, and of client silence before the robot stops.
    """

    robot_class: str = "Pioneer"
    subclass: str = "p2dx"
    angle_conv: float = 2 * math.pi / 4096
    dist_conv: float = 0.84
    vel_conv: float = 1.0
    range_conv: float = 0.268
    diff_conv: float = 0.0056
    vel2_divisor: int = 20
    max_velocity: float = 2200.0
    max_rvelocity: float = 500.0
    trans_accel: float = 300.0
    trans_decel: float = 300.0
    rot_accel: float = 100.0
    rot_decel: float = 100.0
    robot_radius: float = 250.0
    robot_width: float = 425.0
    robot_length: float = 511.0
    switch_to_baud: int = 38400
    sonar_max_range: float = 5000.0
    sonar_poses: tuple[tuple[float, float, float], ...] = (
        (69, 136, 90), (114, 119, 50), (148, 78, 30), (166, 27, 10),
        (166, -27, -10), (148, -78, -30), (114, -119, -50), (69, -136, -90),
        (-157, -136, -90), (-203, -119, -130), (-237, -78, -150), (-255, -27, -170),
        (-255, 27, 170), (-237, 78, 150), (-203, 119, 130), (-157, 136, 90),
    )
    sip_cycle: float = 0.1
    watchdog: float = 2.0

    @property
    def wheel_base(self) -> float:
        """Effective distance between the wheels, metres (2 / DiffConvFactor mm)."""
        return 2.0 / self.diff_conv / 1000.0

    @property
    def max_speed(self) -> float:
        """Largest translational speed VEL may command, m/s."""
        return self.max_velocity / 1000.0

    @property
    def max_turn_rate(self) -> float:
        """Largest rotational speed RVEL may command, rad/s."""
        return math.radians(self.max_rvelocity)


P2DX = RobotParams()
