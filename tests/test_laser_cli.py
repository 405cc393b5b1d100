"""``asrmap probe laser`` and ``asrmap emulate laser``: thin shells over laser.probe."""

from __future__ import annotations

import signal

from service.cli import main


def test_probe_laser_against_the_emulator_prints_type_config_and_scan_summary(capsys):
    assert main(["probe", "laser", "--emulated", "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    for words in ("LMS200;30106", "found at 9600 baud, now 38400", "181 values", "units mm", "Hz", "median"):
        assert words in out


def test_probe_laser_without_a_device_is_one_line_saying_what_to_check(capsys):
    assert main(["probe", "laser", "--port", "/dev/no-such-lms"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/dev/no-such-lms does not exist" in err[0] and "udev" in err[0]


def test_emulate_laser_prints_the_pty_path(capsys):
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert main(["emulate", "laser", "--seconds", "0.1"]) == 0
    finally:  # the command installs its own handlers; keep pytest's Ctrl-C working
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    assert capsys.readouterr().out.startswith("laser: /dev/")
