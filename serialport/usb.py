"""The USB adapter behind a tty, from sysfs, and the FTDI latency timer.

An FTDI chip holds received bytes for up to ``latency_timer`` ms (16 by default) before it hands
them to the host: a scan's arrival (hence its timestamp) and each SIP would be up to 16 ms late and
jittery. 1 ms is set here when this process may (root, or the udev rule's group permissions),
else through the kernel's low-latency flag, else a warning names the udev rule that sets it.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from serialport.diagnose import RULES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Adapter:
    """What sysfs says of a tty: ``tty`` name (ttyUSB0), kernel ``driver`` (ftdi_sio, pl2303, cp210x),
    USB ``vid``/``pid`` (hex strings), ``manufacturer``, ``product``, ``serial`` (may be empty) and
    ``latency_timer`` (ms; None when the driver has none)."""

    tty: str
    driver: str = ""
    vid: str = ""
    pid: str = ""
    manufacturer: str = ""
    product: str = ""
    serial: str = ""
    latency_timer: int | None = None

    def __str__(self) -> str:
        ident = f"{self.vid}:{self.pid}" if self.vid else "not USB"
        words = " ".join(w for w in (self.manufacturer, self.product) if w)
        out = f"{self.tty}: {ident}, driver {self.driver or '?'}"
        out += f", {words}" if words else ""
        out += f", serial {self.serial}" if self.serial else ""
        if self.latency_timer is not None:
            out += f", latency_timer {self.latency_timer} ms"
        return out


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def adapter_of(port: str, sys_root: str = "/sys") -> Adapter | None:
    """The adapter behind ``port`` (a device path; symlinks such as /dev/sick resolved), or None for a
    tty without a sysfs device (a pty, a URL)."""
    if "://" in port:
        return None
    name = os.path.basename(os.path.realpath(port))
    dev = Path(sys_root, "class", "tty", name, "device")
    if not dev.exists():
        return None
    driver = os.path.basename(os.path.realpath(dev / "driver")) if (dev / "driver").exists() else ""
    latency = _read(dev / "latency_timer")
    usb = {}
    # Walk up from the interface towards the USB device node, which carries idVendor/idProduct.
    node = Path(os.path.realpath(dev))
    for _ in range(6):
        if (node / "idVendor").exists():
            usb = {k: _read(node / f) for k, f in (("vid", "idVendor"), ("pid", "idProduct"),
                                                   ("manufacturer", "manufacturer"), ("product", "product"),
                                                   ("serial", "serial"))}
            break
        node = node.parent
    return Adapter(tty=name, driver=driver, latency_timer=int(latency) if latency.isdigit() else None, **usb)


def check_latency(port: str, ser: Any = None, sys_root: str = "/sys", want: int = 1) -> str | None:
    """Bring the latency timer of ``port``'s adapter to ``want`` ms; None when it is (or there is no
    timer), else the warning logged (naming the udev rule that fixes it for good)."""
    adapter = adapter_of(port, sys_root)
    if adapter is None or adapter.latency_timer is None or adapter.latency_timer <= want:
        return None
    path = Path(sys_root, "class", "tty", adapter.tty, "device", "latency_timer")
    try:
        path.write_text(f"{want}\n")
    except OSError:
        if ser is not None and hasattr(ser, "set_low_latency_mode"):
            try:  # ASYNC_LOW_LATENCY: ftdi_sio maps it to a 1 ms timer on kernels that support it
                ser.set_low_latency_mode(True)
            except (OSError, ValueError, NotImplementedError):
                pass
    now = _read(path)
    if now.isdigit() and int(now) <= want:
        log.info("%s: FTDI latency_timer set from %d to %s ms", adapter.tty, adapter.latency_timer, now)
        return None
    msg = (f"{port} ({adapter.tty}): FTDI latency_timer is {now or adapter.latency_timer} ms and could "
           f"not be set to {want} ms: readings arrive up to that much late; install {RULES} (it sets "
           f"ATTR{{latency_timer}}=\"1\") or run: echo 1 | sudo tee {path}")
    log.warning("%s", msg)
    return msg
