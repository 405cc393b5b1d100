"""Opening serial ports: each failure names its cause and its fix, with conditions made for real (a
missing path, a dangling udev symlink, a port locked by another holder, a path the kernel refuses
with EACCES); the adapter and its FTDI latency timer as a sysfs tree describes them."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest

from laser import LinkLost, LMS2xx
from pioneer import Pioneer, PortUnavailable
from serialport import PortError, adapter_of, check_latency, explain, holders, open_port, unsupported_baud


def test_a_missing_port_says_plug_in_the_adapter_and_check_the_udev_rule():
    with pytest.raises(PortError) as info:
        open_port("/dev/no-such-port", 9600, timeout=0.1, what="the Pioneer")
    assert info.value.kind == "missing"
    assert str(info.value).startswith("cannot open the Pioneer port: /dev/no-such-port does not exist; "
                                      "check that the USB adapter is plugged in")
    assert "99-asrmap-serial.rules" in str(info.value)


def test_a_dangling_udev_symlink_says_the_adapter_was_unplugged(tmp_path):
    link = tmp_path / "sick"
    link.symlink_to("/dev/ttyUSB97")
    with pytest.raises(PortError, match=r"to /dev/ttyUSB97, which is gone: the adapter was unplugged"):
        open_port(str(link), 38400, timeout=0.1)


def test_a_busy_port_names_the_process_holding_it(pty_pair):
    holder = os.open(pty_pair.path, os.O_RDWR | os.O_NOCTTY)
    fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as another pyserial client with exclusive=True
    try:
        with pytest.raises(PortUnavailable) as info:
            Pioneer(pty_pair.path)
        msg = str(info.value)
        assert f"{pty_pair.path} is in use: held by pid {os.getpid()} (this process)" in msg
        assert "systemctl stop asrmap" in msg
        with pytest.raises(LinkLost, match="is in use: held by pid"):
            LMS2xx(pty_pair.path)
    finally:
        os.close(holder)


def test_holders_are_found_through_proc_fd_links(pty_pair, tmp_path):
    link = tmp_path / "dev"
    link.symlink_to(pty_pair.path)
    assert os.getpid() in [pid for pid, _ in holders(str(link))]  # the pair keeps its slave side open


def test_permission_denied_names_the_dialout_group_and_device_allow():
    # sysfs refuses write access to a read-only attribute with EACCES even to root: a real EACCES
    # from open(2) without needing an unprivileged user.
    path = "/sys/class/tty/console/dev"
    if not os.path.exists(path):
        pytest.skip("no sysfs tty class here")
    with pytest.raises(PortError) as info:
        open_port(path, 9600, timeout=0.1, what="the LMS2xx")
    msg = str(info.value)
    assert info.value.kind == "permission"
    assert msg.startswith(f"cannot open the LMS2xx port: permission denied on {path} "
                          "(owner root:root, mode 0444)")
    assert "usermod -aG dialout" in msg and "SupplementaryGroups=dialout" in msg and "DeviceAllow=" in msg


def test_a_rate_the_adapter_refuses_says_500000_needs_an_rs422_adapter():
    err = explain("/dev/sick", ValueError("Invalid baud rate: 500000"), 500000, "the LMS2xx")
    assert err.kind == "baud" and "RS-422" in str(err) and "power-cycle the LMS" in str(err)
    assert unsupported_baud("/dev/sick", 19200).startswith("/dev/sick cannot run at 19200 baud")


def _sysfs(root: Path, latency: str = "16", driver: str = "ftdi_sio") -> Path:
    """A sysfs tree as the kernel lays it out for an FT232R on ttyUSB0."""
    usbdev = root / "devices/pci0000:00/usb1/1-1"
    iface = usbdev / "1-1:1.0/ttyUSB0"
    iface.mkdir(parents=True)
    for name, value in (("idVendor", "0403"), ("idProduct", "6001"), ("manufacturer", "FTDI"),
                        ("product", "FT232R USB UART"), ("serial", "SICKLMS01")):
        (usbdev / name).write_text(value + "\n")
    (iface / "latency_timer").write_text(latency + "\n")
    drv = root / "bus/usb-serial/drivers" / driver
    drv.mkdir(parents=True)
    (iface / "driver").symlink_to(drv)
    tty = root / "class/tty/ttyUSB0"
    tty.mkdir(parents=True)
    (tty / "device").symlink_to(iface)
    return iface


def test_the_adapter_is_identified_from_sysfs(tmp_path):
    _sysfs(tmp_path)
    a = adapter_of("/dev/ttyUSB0", sys_root=str(tmp_path))
    assert str(a) == ("ttyUSB0: 0403:6001, driver ftdi_sio, FTDI FT232R USB UART, serial SICKLMS01, "
                      "latency_timer 16 ms")
    assert adapter_of("socket://localhost:8101") is None


def test_an_ftdi_latency_timer_is_set_to_1_ms_where_writable(tmp_path):
    iface = _sysfs(tmp_path)
    assert check_latency("/dev/ttyUSB0", sys_root=str(tmp_path)) is None
    assert (iface / "latency_timer").read_text().strip() == "1"


def test_a_latency_timer_that_cannot_be_set_is_a_warning_naming_the_udev_rule(tmp_path):
    # A read-only sysfs attribute holding a number refuses the write with EACCES, even to root.
    readonly = Path("/sys/class/net/lo/type")
    if not readonly.exists():
        pytest.skip("no sysfs net class here")
    iface = _sysfs(tmp_path)
    (iface / "latency_timer").unlink()
    (iface / "latency_timer").symlink_to(readonly)
    msg = check_latency("/dev/ttyUSB0", sys_root=str(tmp_path))
    value = readonly.read_text().strip()
    assert msg is not None and f"latency_timer is {value} ms and could not be set to 1 ms" in msg
    assert "99-asrmap-serial.rules" in msg


def test_the_udev_rule_sets_the_ftdi_latency_timer_to_1_ms():
    rules = (Path(__file__).parent.parent / "systemd" / "99-asrmap-serial.rules").read_text()
    line = next(r for r in rules.splitlines() if "latency_timer" in r and not r.startswith("#"))
    assert 'DRIVERS=="ftdi_sio"' in line and 'ATTR{latency_timer}="1"' in line
