"""``asrmap run``: the live service on real hardware (what systemd starts)."""

from __future__ import annotations

import signal
import threading

from service import config
from service.pipeline import Service

NAME = "run"
HELP = "the live mapping service: Pioneer and laser on serial ports, map on Zenoh and in the store"
EXAMPLE = "asrmap run --config /etc/asrmap/asrmap.toml"


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
    return Service(cfg).run(stop)
