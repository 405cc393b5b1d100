"""``asrmap monitor``: robots alive on Zenoh, their maps, live status and events."""

from __future__ import annotations

import signal
import sys
import threading

from service.argtypes import non_negative, output_file, robot_or_every
from service.monitor import Monitor, SvgWriter, discover, format_update

NAME = "monitor"
HELP = "watch robots over Zenoh: liveliness, each map from its queryable, live status and events"
EXAMPLE = "asrmap monitor --robot pioneer --connect tcp/192.168.1.20:7447 --svg map.svg"


def add_arguments(p) -> None:
    p.add_argument("--robot", default="*", type=robot_or_every,
                   help="robot name to watch (default: every robot)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint of the robot or a router (default tcp/127.0.0.1:7447; repeatable)")
    p.add_argument("--svg", metavar="OUT", type=output_file,
                   help="keep a picture of the map current in OUT ('{robot}' in OUT: one file per robot)")
    p.add_argument("--once", action="store_true",
                   help="list the robots alive and their maps, then exit (1 if none answered)")
    p.add_argument("--wait", type=non_negative, default=2.0, metavar="S",
                   help="with --once: how long to wait for robots (s, default 2)")


def run(args) -> int:
    connect = args.connect or ["tcp/127.0.0.1:7447"]
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
    # The session is closed in every case: an open zenoh session keeps the interpreter alive.
    svg = SvgWriter(args.svg) if args.svg else None
    with Monitor(connect, args.robot) as mon:
        if args.once:
            updates = discover(mon, args.wait, stop)
            if stop.is_set():
                return 130  # interrupted: what was heard so far is not an answer
            for u in updates:
                if u.kind in ("alive", "map"):
                    print(format_update(u), flush=True)
            for path in svg.update(mon) if svg else ():
                print(f"wrote {path}", flush=True)
            if any(u.kind == "alive" for u in updates):
                return 0
            print(f"asrmap monitor: no robot {args.robot!r} alive through {', '.join(connect)} within "
                  f"{args.wait:g} s (is the service running, and listening there?)", file=sys.stderr)
            return 1
        print(f"watching asrmap/{args.robot}/ through {', '.join(connect)} (Ctrl-C to stop)", flush=True)
        while not stop.is_set():
            for u in mon.poll(0.2):
                print(format_update(u), flush=True)
            if svg:
                svg.update(mon)
    return 0
