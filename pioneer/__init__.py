"""P2OS for the Pioneer 2DX: packet codec, SIP decoding, host-side driver, robot-side emulator.

``from pioneer import Pioneer`` for the driver and its :class:`PioneerOdometry` records; the
emulator is :class:`pioneer.emulator.PioneerEmulator` (robot side, on a pty master), and
:func:`pioneer.probe.probe` is the bring-up check behind ``asrmap probe pioneer``.
"""

from pioneer.driver import Identity, Pioneer, Timeouts
from pioneer.errors import LinkLost, PioneerError, PortUnavailable, ProtocolError
from pioneer.odometry import PioneerOdometry
from pioneer.params import P2DX, RobotParams
from pioneer.physics import OdometryError
from pioneer.sip import SIP, decode_sip, encode_sip

__all__ = [
    "P2DX",
    "SIP",
    "Identity",
    "LinkLost",
    "OdometryError",
    "Pioneer",
    "PioneerError",
    "PioneerOdometry",
    "PortUnavailable",
    "ProtocolError",
    "RobotParams",
    "Timeouts",
    "decode_sip",
    "encode_sip",
]
