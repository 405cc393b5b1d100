"""Opening serial ports with diagnostics a person can act on, shared by both device drivers.

:func:`open_port` opens a device path or any ``serial.serial_for_url`` URL; a path is locked
exclusively (a second program on the same robot port garbles both), the USB adapter behind it is
identified from sysfs and logged, and an FTDI's latency timer is brought to 1 ms. Failures raise
:class:`PortError` whose message names the cause and the remedy (:mod:`serialport.diagnose`).
"""

from serialport.diagnose import PortError, explain, holders, unsupported_baud
from serialport.open import open_port
from serialport.usb import Adapter, adapter_of, check_latency

__all__ = ["Adapter", "PortError", "adapter_of", "check_latency", "explain", "holders", "open_port",
           "unsupported_baud"]
