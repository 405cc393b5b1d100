"""SIGKILL durability: the service is killed again and again during a replay of a real log; every
map restored from the store holds everything that was published before the kill."""

from __future__ import annotations

import json
import random
import sys
import threading
import time

import zenoh

from service.bench.service import ServiceProcess, free_port, write_config
from service.bus import client_config
from service.store import MapStore

LOG = "intel-raw-first5505.clf.gz"


class Published:
    """What a subscriber saw: the last payload of each ASR, and the newest pose time."""

    def __init__(self, session: zenoh.Session, robot: str):
        self.lock = threading.Lock()
        self.asrs: dict[int, dict] = {}
        self.pose_t = -1.0
        self._subs = [
            session.declare_subscriber(f"asrmap/{robot}/asr/*", self._asr),
            session.declare_subscriber(f"asrmap/{robot}/pose", self._pose),
        ]

    def _asr(self, s: zenoh.Sample) -> None:
        d = json.loads(s.payload.to_bytes())
        d.pop("schema")
        with self.lock:
            self.asrs[d["id"]] = d

    def _pose(self, s: zenoh.Sample) -> None:
        with self.lock:
            self.pose_t = max(self.pose_t, json.loads(s.payload.to_bytes())["t"])

    def snapshot(self) -> tuple[dict[int, dict], float]:
        with self.lock:
            return dict(self.asrs), self.pose_t


def _map(session: zenoh.Session) -> dict:
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        for r in session.get("asrmap/dur/map", timeout=2.0):
            if r.ok:
                return json.loads(r.ok.payload.to_bytes())
        time.sleep(0.1)
    raise AssertionError("the restarted service did not answer the map query")


def _check_restored(stored: dict, published: dict[int, dict]) -> None:
    by_id = {a["id"]: a for a in stored["asrs"]}
    missing = sorted(set(published) - set(by_id))
    assert not missing, f"published ASRs {missing} are not in the store"
    # The store is committed before each publication, so it can only be ahead: an ASR killed
    # between its commit and its put is newer in the store, never older.
    for i, pub in published.items():
        if by_id[i] != pub:
            assert by_id[i]["scans"] >= pub["scans"], f"ASR {i} went back from {pub} to {by_id[i]}"


def test_every_restored_map_holds_what_was_published_before_each_sigkill(tmp_path, shared_data):
    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = write_config(tmp_path / "asrmap.toml", robot={"name": "dur"}, zenoh={"listen": [ep]},
                       store={"state_dir": str(tmp_path)}, mapper={"laser_x": 0.0, "laser_y": 0.0},
                       watchdog={"scan_timeout": 5.0, "odometry_timeout": 5.0})
    rng = random.Random(7)
    session = zenoh.open(client_config([ep]))
    try:
        seen = Published(session, "dur")
        start, ever = -1.0, set()
        for _ in range(3):
            child = ServiceProcess(cfg, tmp_path, args=[
                sys.executable, "-m", "tests.service_harness", "replay", "--config", str(cfg),
                "--log", str(shared_data / LOG), "--start", str(start), "--rate", "60"])
            try:
                child.notify.wait_for("READY=1", 30)
                if ever:  # the restarted service serves the restored map
                    assert ever <= {a["id"] for a in _map(session)["asrs"]}
                time.sleep(rng.uniform(0.8, 1.6))
            finally:
                child.kill()
                child.close()
            published, start = seen.snapshot()
            with MapStore(tmp_path / "map.sqlite") as s:
                stored = s.load()
            assert stored is not None and published, "nothing was mapped and published"
            _check_restored(stored, published)
            # Nothing mapped in an earlier run disappears: the map continues across restarts.
            ever |= set(published)
            assert ever <= {a["id"] for a in stored["asrs"]}
    finally:
        session.close()
