"""``asrmap emulate DEVICE``: run an emulated device on a new pty, print the device path for any
client (ARIA, Player, ROS-p2os, asrmap itself), and keep it running until Ctrl-C or SIGTERM."""

from __future__ import annotations

import contextlib
import signal
import threading

from service.argtypes import positive

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


def _emulate_world(args, stack: contextlib.ExitStack) -> dict[str, str]:
    from service.sim.simulator import WorldDevices
    from service.sim.world import load_world

    devices = stack.enter_context(WorldDevices(load_world(args.world)))
    return {"pioneer": devices.pioneer_path, "laser": devices.laser_path}


def add_arguments(p) -> None:
    p.add_argument("device", nargs="?", choices=sorted(DEVICES),
                   help="which device to emulate (with --world: both, in that world)")
    p.add_argument("--world", metavar="NAME|FILE",
                   help="both devices in a simulated world (lab, office, aliasing or a world .json): the "
                        "Pioneer moves in it (collisions stall it), the laser sees it")
    p.add_argument("--name", help="the name the device reports (pioneer: SYNC2 robot name)")
    p.add_argument("--seconds", type=positive, default=None,
                   help="stop after this long (default: run until Ctrl-C or SIGTERM)")


def run(args) -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.device is None and args.world is None:
        raise ValueError("name a device (pioneer, laser) or give --world NAME")
    with contextlib.ExitStack() as stack:
        if args.world:
            paths = _emulate_world(args, stack)
        else:
            paths = {args.device: DEVICES[args.device](args, stack)}
        for device, path in paths.items():
            print(f"{device}: {path}", flush=True)
        stop.wait(args.seconds)
    return 0
