"""``asrmap emulate DEVICE``: run an emulated device on a new pty, print the device path for any
client (ARIA, Player, ROS-p2os, asrmap itself), and keep it running until Ctrl-C or SIGTERM."""

from __future__ import annotations

import contextlib
import signal
import threading

NAME = "emulate"
HELP = "run emulated devices on pseudo-terminals and print their paths, until Ctrl-C/SIGTERM"
EXAMPLE = "asrmap emulate pioneer"


def _emulate_pioneer(args, stack: contextlib.ExitStack) -> str:
    from pioneer.probe import emulated

    path, _ = stack.enter_context(emulated(name=args.name or "asrmap-emu"))
    return path


def _emulate_laser(args, stack: contextlib.ExitStack) -> str:
    from laser.probe import emulated_laser

    pair, _ = stack.enter_context(emulated_laser())  # a fixed synthetic room, powered on at 9600 baud
    return pair.path


# One entry per device; each starts its emulator inside ``stack`` and returns the pty path.
DEVICES = {"pioneer": _emulate_pioneer, "laser": _emulate_laser}


def add_arguments(p) -> None:
    p.add_argument("device", choices=sorted(DEVICES), help="which device to emulate")
    p.add_argument("--name", help="the name the device reports (pioneer: SYNC2 robot name)")
    p.add_argument("--seconds", type=float, default=None,
                   help="stop after this long (default: run until Ctrl-C or SIGTERM)")


def run(args) -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with contextlib.ExitStack() as stack:
        path = DEVICES[args.device](args, stack)
        print(f"{args.device}: {path}", flush=True)
        stop.wait(args.seconds)
    return 0
