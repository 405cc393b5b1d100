"""Why a serial port did not open, in words that say what to do (one line, no newline).

Each cause has a fixed opening so the README's troubleshooting table can be keyed by it:

- ``... does not exist`` (ENOENT, ENODEV, ENXIO: nothing there, or a udev symlink left dangling),
- ``... permission denied`` (EACCES, EPERM: not in the dialout group, or systemd's DeviceAllow=),
- ``... is in use`` (EBUSY, or another program holds pyserial's exclusive flock; the holders are
  found by scanning ``/proc/*/fd`` when this process may read them),
- ``... cannot run at N baud`` (the adapter or its driver refuses the rate).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

MISSING = "missing"
PERMISSION = "permission"
BUSY = "busy"
BAUD = "baud"
OTHER = "other"

_MISSING = {errno.ENOENT, errno.ENODEV, errno.ENXIO}
_PERMISSION = {errno.EACCES, errno.EPERM}
_BUSY = {errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK}

RULES = "systemd/99-asrmap-serial.rules"


class PortError(ConnectionError):
    """A port that could not be opened; ``kind`` is one of missing, permission, busy, baud, other."""

    def __init__(self, message: str, kind: str = OTHER, port: str = ""):
        super().__init__(message)
        self.kind = kind
        self.port = port


def holders(path: str, proc: str = "/proc") -> list[tuple[int, str]]:
    """``(pid, command line)`` of every process with ``path`` (symlinks resolved) open, found by
    reading the ``/proc/<pid>/fd`` links; processes this one may not inspect are skipped."""
    target = os.path.realpath(path)
    found = []
    for entry in Path(proc).iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fds = list((entry / "fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                if os.readlink(fd) == target:
                    break
            except OSError:
                continue
        else:
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            cmd = ""
        found.append((int(entry.name), cmd or "?"))
    return found


def _who(path: str) -> str:
    me = os.getpid()
    try:
        procs = holders(path)
    except OSError:
        procs = []
    procs = [(pid, cmd) for pid, cmd in procs if pid != me] or procs
    if not procs:
        return ("another program holds it (which one could not be told: no readable /proc/<pid>/fd "
                "links to it)")
    names = ", ".join(f"pid {pid}{' (this process)' if pid == me else ''}: {cmd[:80]}" for pid, cmd in procs)
    return f"held by {names}"


def unsupported_baud(port: str, baudrate: int, detail: str = "") -> str:
    """The message for an adapter that refuses ``baudrate`` (500000 needs an RS-422 adapter that
    can do it, e.g. an FTDI-based one; many PL2303/CH340 adapters cannot)."""
    extra = f" ({detail})" if detail else ""
    hint = ("500000 baud is only reachable through an RS-422 adapter whose chip supports it (FTDI "
            "FT232R/FT4232 do); use such an adapter, or power-cycle the LMS (it starts at 9600 baud) and set "
            "laser.baudrate = 38400" if baudrate == 500000 else
            "use a rate the device and adapter both support")
    return f"{port} cannot run at {baudrate} baud: the adapter or its driver refused the rate{extra}; {hint}"


def explain(port: str, exc: BaseException, baudrate: int | None = None,
            what: str = "the device") -> PortError:
    """A :class:`PortError` for ``exc`` raised while opening ``port`` for ``what`` ("the Pioneer")."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if isinstance(exc, ValueError) and "baud" in text.lower() and baudrate is not None:
        return PortError(f"cannot open {what} port: {unsupported_baud(port, baudrate, text)}", BAUD, port)
    if "exclusively lock" in text or code in _BUSY:
        return PortError(
            f"cannot open {what} port: {port} is in use: {_who(port)}; stop that program (an earlier "
            f"asrmap, ARIA, Player, ROS, a terminal such as minicom: 'systemctl stop asrmap' or 'kill PID') "
            f"and try again", BUSY, port)
    if code in _PERMISSION or isinstance(exc, PermissionError):
        try:
            st = os.stat(port)
            import grp
            import pwd

            mode = (f" (owner {pwd.getpwuid(st.st_uid).pw_name}:{grp.getgrgid(st.st_gid).gr_name}, "
                    f"mode {st.st_mode & 0o777:04o})")
        except (OSError, KeyError):
            mode = ""
        return PortError(
            f"cannot open {what} port: permission denied on {port}{mode}; add the user to the dialout group "
            f"(sudo usermod -aG dialout $USER, then log in again); under systemd keep "
            f"SupplementaryGroups=dialout and a DeviceAllow= line for this path in asrmap.service; the "
            f"udev rules ({RULES}) leave the port root:dialout 0660", PERMISSION, port)
    if code in _MISSING or isinstance(exc, FileNotFoundError):
        dangling = ""
        if os.path.islink(port):
            dangling = f" (it is a symlink to {os.readlink(port)}, which is gone: the adapter was unplugged)"
        return PortError(
            f"cannot open {what} port: {port} does not exist{dangling}; check that the USB adapter is "
            f"plugged in (ls -l /dev/serial/by-id/), that the udev rules ({RULES}) are installed with this "
            f"adapter's serial number (udevadm info --attribute-walk --name=/dev/ttyUSB0 | grep serial), "
            f"or name the port in the config", MISSING, port)
    at = f" at {baudrate} baud" if baudrate else ""
    return PortError(f"cannot open {what} port {port}{at}: {text}", OTHER, port)
