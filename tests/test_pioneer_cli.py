"""``asrmap probe pioneer`` and ``asrmap emulate pioneer``."""

from __future__ import annotations

import signal
import subprocess
import sys

from pioneer import Identity, Pioneer, Timeouts
from service.cli import main


def test_probe_emulated_prints_identity_and_decoded_sips_and_exits_0(capsys):
    assert main(["--log-level", "WARNING", "probe", "pioneer", "--emulated", "--seconds", "0.35"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("robot    'asrmap-emu', class Pioneer, subclass p2dx")
    assert out[1].startswith("config   firmware")
    sips = [line for line in out if "batt 12.5 V" in line]
    assert len(sips) >= 2 and all("motors off" in s for s in sips)  # a probe never enables the motors


def test_probe_of_a_missing_port_is_one_line_saying_what_to_check(capsys):
    assert main(["probe", "pioneer", "--port", "/dev/no-such-pioneer"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("asrmap probe: cannot open the Pioneer port: /dev/no-such-pioneer does not "
                             "exist")
    assert "plugged in" in err[0]


def test_probe_without_port_or_emulated_says_so(capsys):
    assert main(["probe", "pioneer"]) == 2
    assert "needs --port" in capsys.readouterr().err


def test_emulate_pioneer_prints_a_device_any_driver_can_open_and_stops_on_sigterm():
    cmd = [sys.executable, "-m", "service.cli", "--log-level", "WARNING", "emulate", "pioneer",
           "--name", "clibot"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().strip()
        assert line.startswith("pioneer: /dev/")
        with Pioneer(line.split(": ", 1)[1], timeouts=Timeouts(sync_reply=0.3, sync_attempts=5)) as robot:
            assert robot.identity == Identity("clibot", "Pioneer", "p2dx")
            assert robot.wait_odometry(1.0) is not None
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5) == 0
    finally:
        proc.kill()
