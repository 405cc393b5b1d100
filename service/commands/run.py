"""``asrmap run``: the live service on real hardware (what systemd starts)."""

from __future__ import annotations

import gc
import signal
import sys
import threading

from service import config
from service.pipeline import Service

NAME = "run"
HELP = "the live mapping service: Pioneer and laser on serial ports, map on Zenoh and in the store"
EXAMPLE = "asrmap run --config /etc/asrmap/asrmap.toml"

SWITCH_INTERVAL = 0.001  # s


def add_arguments(p) -> None:
    p.add_argument("--config", required=True, metavar="FILE",
                   help="TOML configuration (every key is documented in systemd/asrmap.toml)")


def run(args) -> int:
    cfg = config.load(args.config)
    stop = threading.Event()

    def on_signal(signum, frame) -> None:
        # Only set the flag: the main loop ends and its `finally` stops the robot and closes Zenoh
        # (raising here could skip that, and an unclosed zenoh session never lets the process exit).
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, on_signal)
    # The serial reader threads wait for the GIL while the mapper computes; at the default 5 ms
    # switch interval each of their few acquisitions per telegram can cost up to 5 ms of latency.
    sys.setswitchinterval(SWITCH_INTERVAL)
    # Everything imported so far lives as long as the process: keep it out of the collector's
    # full passes, which otherwise stall every thread for milliseconds.
    gc.freeze()
    return Service(cfg).run(stop)
