"""``asrmap probe DEVICE``: hardware bring-up. Connect, print what the device reports, exit 0; or
exit non-zero with one line saying what to check (the driver's error message)."""

from __future__ import annotations

from service.argtypes import positive

NAME = "probe"
HELP = "hardware bring-up: connect to a device and print what it reports"
EXAMPLE = "asrmap probe pioneer --port /dev/ttyUSB0   (or: asrmap probe pioneer --emulated)"


def _probe_pioneer(args) -> int:
    from pioneer.probe import emulated, probe

    baud = args.baud or 9600
    if args.emulated:
        with emulated() as (path, _):
            report = probe(path, baud, args.seconds)
    elif not args.port:
        raise ValueError("probe pioneer needs --port DEV (/dev/ttyUSB0, socket://host:8101) or --emulated")
    else:
        report = probe(args.port, baud, args.seconds)
    for line in report.lines():
        print(line)
    return 0


def _probe_laser(args) -> int:
    from laser.probe import emulated_laser, probe

    baud = args.baud or 38400
    if args.emulated:
        with emulated_laser() as (pair, _):
            report = probe(pair.path, baud, duration=args.seconds)
    elif not args.port:
        raise ValueError("probe laser needs --port DEV (/dev/ttyUSB0, socket://host:port) or --emulated")
    else:
        report = probe(args.port, baud, duration=args.seconds)
    for line in report.lines():
        print(line)
    return 0


# One entry per device; each takes the parsed arguments and returns the exit status.
DEVICES = {"pioneer": _probe_pioneer, "laser": _probe_laser}


def add_arguments(p) -> None:
    p.add_argument("device", choices=sorted(DEVICES), help="which device to probe")
    p.add_argument("--port", help="serial device or pyserial URL (socket://host:port for ser2net/MobileSim)")
    p.add_argument("--baud", type=int, default=None, help="baud rate (default: the device's factory rate)")
    p.add_argument("--seconds", type=positive, default=2.0, help="how long to record what the device sends")
    p.add_argument("--emulated", action="store_true",
                   help="probe an emulated device started in-process on a pty (no hardware needed)")


def run(args) -> int:
    return DEVICES[args.device](args)
