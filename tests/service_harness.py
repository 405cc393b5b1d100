"""``python -m tests.service_harness replay ...``: the service wired exactly as ``asrmap run``
(mapper thread, store, Zenoh) but fed from a CARMEN log through stand-in devices, for the SIGKILL
durability test. (The robot-on-ptys harness lives in :mod:`service.bench.service`.)
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

# --- the replay child for the SIGKILL durability test ----------------------------------------------------


class _Player:
    """Plays a CARMEN log's odometry and scans to the stand-in devices, ``rate`` scans per second."""

    def __init__(self, log: str, start: float, rate: float):
        from service.carmen import mapper_inputs

        self.inputs = [r for r in mapper_inputs(log) if r.t > start - 1.0]
        self.start, self.rate = start, rate
        self.odometry: list = []
        self.scans: list = []
        self._go = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        from mapper.types import Scan

        self._go.wait()
        for r in self.inputs:
            if isinstance(r, Scan):
                if r.t <= self.start:
                    continue
                for cb in self.scans:
                    cb(r)
                time.sleep(1.0 / self.rate)
            else:
                for cb in self.odometry:
                    cb(r)
        print("replay finished", flush=True)

    def device(self, kind: str):
        player = self

        class Device:
            def __init__(self):
                # The stand-in stays "alive" with a heartbeat between readings: silence is not a fault.
                self.closed = threading.Event()

            def on_odometry(self, cb):
                player.odometry.append(cb)
                player._go.set()

            def on_scan(self, cb):
                player.scans.append(cb)

            def stop(self):
                pass

            def close(self):
                self.closed.set()

        return Device()


def replay_main(argv: list[str]) -> int:
    from service import config
    from service.pipeline import Service

    ap = argparse.ArgumentParser()
    ap.add_argument("--config", required=True)
    ap.add_argument("--log", required=True)
    ap.add_argument("--start", type=float, default=-1.0, help="replay scans after this log time (s)")
    ap.add_argument("--rate", type=float, default=40.0)
    a = ap.parse_args(argv)
    cfg = config.load(a.config)
    player = _Player(a.log, a.start, a.rate)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return Service(cfg, open_pioneer=lambda c: player.device("pioneer"),
                   open_laser=lambda c: player.device("laser")).run(stop)


if __name__ == "__main__":
    if sys.argv[1:2] == ["replay"]:
        sys.exit(replay_main(sys.argv[2:]))
    sys.exit(f"usage: {sys.argv[0]} replay --config FILE --log LOG [--start T] [--rate HZ]")
