"""The service's pipeline parts: time alignment, the drop-oldest queue, device links, the mapper
thread, and the whole lifecycle with in-process stand-in devices and mapper (the end-to-end tests
against the emulators through the real drivers are in test_service_run.py)."""

from __future__ import annotations

import dataclasses
import json
import math
import queue
import socket
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import zenoh

from mapper.events import AsrCreated, AsrUpdated
from service.bench.service import free_port
from service.buffers import DropOldest, OdometryBuffer
from service.bus import client_config
from service.config import Config, StoreConfig, WatchdogConfig, ZenohConfig
from service.device_link import Link
from service.mapper_worker import MapperWorker
from service.notify import Notifier
from service.pipeline import Service
from service.store import MapStore

# --- alignment -----------------------------------------------------------------------------------------


def test_pose_between_two_sips_is_interpolated():
    b = OdometryBuffer()
    b.add(1.0, 0.0, 0.0, 0.0)
    b.add(1.1, 0.1, 0.0, 0.2)
    assert b.at(1.075) == pytest.approx((0.075, 0.0, 0.15))


def test_heading_interpolates_across_pi():
    b = OdometryBuffer()
    b.add(0.0, 0.0, 0.0, math.pi - 0.1)
    b.add(1.0, 0.0, 0.0, -math.pi + 0.1)
    assert abs(b.at(0.5)[2]) == pytest.approx(math.pi)


def test_past_the_newest_sip_the_pose_is_extrapolated_for_a_bounded_time():
    b = OdometryBuffer(max_extrapolation=0.25)
    b.add(0.0, 0.0, 0.0, 0.0)
    b.add(0.1, 0.05, 0.0, 0.0)  # 0.5 m/s
    assert b.at(0.15)[0] == pytest.approx(0.075)
    assert b.at(5.0)[0] == pytest.approx(0.05 + 0.5 * 0.25)


def test_sips_bunched_by_a_late_read_do_not_throw_the_extrapolated_pose_away():
    b = OdometryBuffer(max_extrapolation=0.25, velocity_baseline=0.05)
    for k in range(5):  # 0.5 m/s, SIPs every 100 ms
        b.add(0.1 * k, 0.05 * k, 0.0, 0.0)
    b.add(0.4 + 1e-6, 0.205, 0.0, 0.0)  # the next SIP completed by the same read: 1 us later, 5 mm on
    # The velocity comes from SIPs at least 50 ms apart (0.5 m/s, not 5000 m/s).
    assert b.at(0.5)[0] == pytest.approx(0.255, abs=0.01)


def test_before_any_odometry_there_is_no_pose_and_before_the_first_the_first_holds():
    b = OdometryBuffer()
    assert b.at(1.0) is None
    b.add(1.0, 2.0, 3.0, 0.5)
    assert b.at(0.0) == (2.0, 3.0, 0.5) and b.at(2.0) == (2.0, 3.0, 0.5)


def test_a_reopened_pioneer_continues_the_odometry_frame():
    b = OdometryBuffer()
    b.add(0.0, 1.0, 2.0, math.pi / 2)
    b.new_session()
    assert b.add(1.0, 0.0, 0.0, 0.0) == pytest.approx((1.0, 2.0, math.pi / 2))
    # 1 m forward in the new session is +y in the continuous frame (the robot faces +y).
    assert b.add(2.0, 1.0, 0.0, 0.0) == pytest.approx((1.0, 3.0, math.pi / 2))


def test_old_odometry_is_forgotten():
    b = OdometryBuffer(history=1.0)
    for i in range(100):
        b.add(i * 0.1, float(i), 0.0, 0.0)
    assert len(b._t) <= 12 and b.latest() == (pytest.approx(9.9), (99.0, 0.0, 0.0))


def test_the_queue_drops_the_oldest_and_counts_it():
    q = DropOldest(3)
    for i in range(5):
        q.put(i)
    assert q.dropped == 2 and [q.get(0), q.get(0), q.get(0), q.get(0)] == [2, 3, 4, None]


# --- links ------------------------------------------------------------------------------------------------


class FakeDevice:
    """Stands in for a driver: calls its callbacks from its own thread every ``period`` seconds."""

    def __init__(self, make, period: float):
        self.make, self.period = make, period
        self.callbacks: list = []
        self.closed = threading.Event()
        self.silent = False
        self.stops = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def on_odometry(self, cb):
        self.callbacks.append(cb)

    on_scan = on_odometry

    def _run(self):
        while not self.closed.wait(self.period):
            if not self.silent:
                for cb in list(self.callbacks):
                    cb(self.make())

    def stop(self):
        self.stops += 1

    def close(self):
        self.closed.set()


def test_a_link_reports_fault_and_recovered_and_reopens():
    changes: queue.Queue = queue.Queue()
    devices: list[FakeDevice] = []
    fail = [True]

    def opener():
        if fail[0]:
            fail[0] = False
            raise OSError("no such device /dev/sick")
        devices.append(FakeDevice(lambda: None, 0.01))
        return devices[-1]

    link = Link("laser", opener, lambda d: d.on_scan(lambda _: link.touch(d)), 0.1, 0.05,
                lambda *c: changes.put(c))
    link.start()
    try:
        assert changes.get(timeout=2) == ("laser", "fault", "cannot open: no such device /dev/sick")
        assert changes.get(timeout=2) == ("laser", "recovered", "")
        devices[0].silent = True
        name, what, reason = changes.get(timeout=2)
        assert (name, what) == ("laser", "fault") and reason.startswith("no data for")
        assert changes.get(timeout=2) == ("laser", "recovered", "")
        assert devices[0].closed.is_set() and len(devices) == 2 and link.faults == 2
    finally:
        link.stop()
    assert devices[-1].closed.is_set()


# --- the mapper thread --------------------------------------------------------------------------------------


class FakeMapper:
    """A mapper that creates ASR n at the n-th scan and updates it on every other scan."""

    def __init__(self, doc=None):
        self.asrs = {a["id"]: a for a in (doc or {}).get("asrs", [])}
        self.n = 0
        self.odometry = []

    def add_odometry(self, o):
        self.odometry.append(o)
        return []

    def add_scan(self, scan):
        self.n += 1
        if self.n % 2:
            i = len(self.asrs) + 1
            self.asrs[i] = {"id": i, "created": scan.t, "scans": 1}
            return [AsrCreated(scan.t, i, (0.0, 0.0, 0.0))]
        a = self.asrs[max(self.asrs)]
        a["scans"] += 1
        return [AsrUpdated(scan.t, a["id"], 1.0, a["scans"])]

    def document(self):
        return {"asrs": [dict(a) for a in self.asrs.values()], "links": [], "cycles": []}


class RecordingBus:
    def __init__(self, store_path):
        self.store_path = store_path
        self.seen: list = []

    def publish_asr(self, asr):
        with MapStore(self.store_path) as s:  # another connection: what is on disk now
            stored = {a["id"]: a for a in s.load()["asrs"]}
        self.seen.append(("asr", asr["id"], stored.get(asr["id"]) == asr))

    def publish_event(self, e):
        self.seen.append(("event", e["event"]))

    def publish_pose(self, p):
        self.seen.append(("pose", p["t"]))


def _scan(t):
    return SimpleNamespace(t=t, ranges=np.full(181, 2.0, dtype=np.float32),
                           angles=np.radians(np.arange(-90, 91, dtype=float)), max_range=8.191)


def test_the_mapper_thread_commits_before_it_publishes(tmp_path):
    odo = OdometryBuffer()
    odo.add(0.0, 0.0, 0.0, 0.0)
    odo.add(10.0, 1.0, 0.0, 0.0)
    with MapStore(tmp_path / "m.sqlite") as store:
        bus = RecordingBus(tmp_path / "m.sqlite")
        w = MapperWorker(FakeMapper(), store, bus, DropOldest(8), odo, "r1", pose_period=100.0,
                         publish_scans=False)
        w.process(_scan(5.0))
        w.process(_scan(6.0))
    assert bus.seen == [("asr", 1, True), ("event", "asr_created"), ("pose", 5.0), ("asr", 1, True)]
    assert w.document["schema"] == "asrmap/map/1" and w.document["robot"] == "r1"
    assert w.mapper.odometry[0].t == 5.0 and w.mapper.odometry[0].x == pytest.approx(0.5)


def test_a_scan_before_any_odometry_is_counted_not_mapped(tmp_path):
    with MapStore(tmp_path / "m.sqlite") as store:
        w = MapperWorker(FakeMapper(), store, None, DropOldest(8), OdometryBuffer(), "r1", 0.1, False)
        assert w.process(_scan(1.0)) == [] and w.counters["scans_without_odometry"] == 1


# --- the whole service with stand-in devices ---------------------------------------------------------------


class Bench:
    """A Service on stand-in devices, run in a thread, with a notify socket and a zenoh client."""

    def __init__(self, tmp_path, allow=(), new_mapper=lambda c, doc: FakeMapper(doc)):
        self.ep = f"tcp/127.0.0.1:{free_port()}"
        self.cfg = dataclasses.replace(
            Config(), zenoh=ZenohConfig(listen=(self.ep,), allow_commands=allow),
            store=StoreConfig(state_dir=str(tmp_path)),
            watchdog=WatchdogConfig(scan_timeout=0.2, odometry_timeout=0.2, reconnect_interval=0.05,
                                    mapper_stall=1.0))
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        (tmp_path / "notify").unlink(missing_ok=True)
        self.notify.bind(str(tmp_path / "notify"))
        self.notify.settimeout(5)
        self.pioneers: list[FakeDevice] = []
        self.lasers: list[FakeDevice] = []
        t0 = time.monotonic()
        self.service = Service(
            self.cfg, notifier=Notifier(environ={"NOTIFY_SOCKET": str(tmp_path / "notify"),
                                                 "WATCHDOG_USEC": "200000"}),
            open_pioneer=lambda c: self._add(self.pioneers, lambda: SimpleNamespace(
                t=time.monotonic(), x=time.monotonic() - t0, y=0.0, theta=0.0, battery=12.5), 0.01),
            open_laser=lambda c: self._add(self.lasers, lambda: _scan(time.monotonic()), 0.02),
            new_mapper=new_mapper)
        self.stop = threading.Event()
        self.result: list = []
        self.thread = threading.Thread(target=lambda: self.result.append(self.service.run(self.stop)))

    def _add(self, where, make, period):
        where.append(FakeDevice(make, period))
        return where[-1]

    def messages(self, until: str) -> list[bytes]:
        got = []
        while not got or until.encode() not in got[-1]:
            got.append(self.notify.recv(4096))
        return got

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(5)
        self.notify.close()


def test_ready_after_both_devices_then_watchdog_then_stopping(tmp_path):
    with Bench(tmp_path) as b:
        msgs = b.messages("READY=1")
        assert msgs[0] == b"STATUS=waiting for the Pioneer and the laser"
        assert b.messages("WATCHDOG=1")
        t = time.monotonic()
        b.stop.set()
        b.thread.join(5)
        assert time.monotonic() - t < 2.0 and b.result == [0]
        assert b.messages("STOPPING=1")
        assert b.pioneers[-1].stops >= 1 and b.pioneers[-1].closed.is_set() and b.lasers[-1].closed.is_set()


def test_a_blind_laser_stops_the_robot_and_is_published_as_fault_then_recovered(tmp_path):
    with Bench(tmp_path) as b:
        b.messages("READY=1")
        s = zenoh.open(client_config([b.ep]))
        try:
            events: queue.Queue = queue.Queue()
            sub = s.declare_subscriber("asrmap/pioneer/event",
                                       lambda x: events.put(json.loads(x.payload.to_bytes())))
            time.sleep(0.3)
            stops = b.pioneers[-1].stops
            b.lasers[-1].silent = True
            fault = next(e for e in iter(lambda: events.get(timeout=3), None) if e["event"] == "fault")
            assert fault["device"] == "laser" and fault["reason"].startswith("no data for")
            assert b.pioneers[-1].stops > stops
            recovered = next(e for e in iter(lambda: events.get(timeout=3), None)
                             if e["event"] == "recovered")
            assert recovered["device"] == "laser" and len(b.lasers) == 2
            status = b.service.status()
            assert status["laser"]["faults"] == 1 and status["laser"]["recoveries"] == 1
            assert status["battery"] == 12.5
            sub.undeclare()
        finally:
            s.close()


def test_the_map_survives_a_restart_of_the_service(tmp_path):
    with Bench(tmp_path) as b:
        b.messages("READY=1")
        time.sleep(0.3)
    with MapStore(tmp_path / "map.sqlite") as s:
        before = s.load()
    assert before and len(before["asrs"]) >= 3
    with Bench(tmp_path) as b:
        b.messages("READY=1")
        assert b.service.worker.mapper.asrs.keys() >= {a["id"] for a in before["asrs"]}


def test_a_stored_map_the_mapper_does_not_continue_is_archived_not_overwritten(tmp_path):
    with Bench(tmp_path) as b:
        b.messages("READY=1")
        time.sleep(0.2)
    with Bench(tmp_path, new_mapper=lambda c, doc: FakeMapper(None)) as b:
        b.messages("READY=1")
    (aside,) = tmp_path.glob("map.sqlite.not-continued-*")
    with MapStore(aside) as s:
        assert len(s.load()["asrs"]) >= 2


def test_a_restart_resumes_at_the_stored_pose_when_it_is_in_the_last_asr(monkeypatch):
    from mapper.mapper import Mapper
    from service.mapper_worker import make_mapper

    calls = []
    monkeypatch.setattr(Mapper, "from_document",
                        classmethod(lambda cls, doc, params, pose: calls.append(pose)))
    doc = {"asrs": [{"id": 1}, {"id": 2}]}
    make_mapper(Config(), {**doc, "resume": (2, (0.5, 0.25, 1.0))})
    make_mapper(Config(), {**doc, "resume": (1, (0.5, 0.25, 1.0))})  # not the ASR it resumes in
    make_mapper(Config(), {**doc, "resume": None})
    assert calls == [(0.5, 0.25, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)]


class _Explorer:
    p = SimpleNamespace(laser_x=0.0, laser_y=0.0)

    def __init__(self, done_after=99):
        self.steps, self.done_after = 0, done_after

    def step(self, view, pts, t, stalled):
        from service.explore import Command

        self.steps += 1
        return Command(0.3, 0.1, "driving", done=self.steps >= self.done_after)


def _exploring(explorer) -> tuple:
    from service.mapper_worker import Exploration

    sent = []
    ex = Exploration(lambda v, w: sent.append((v, w)), lambda: False, period=0.0)
    ex.start()
    ex.explorer = explorer
    return ex, sent


def test_exploration_drives_from_fresh_scans_only():
    ex, sent = _exploring(_Explorer())
    mapper = SimpleNamespace(current=1, pose=(0.0, 0.0, 0.0), asrs={})
    ex.step(mapper, {"links": []}, _scan(time.monotonic()))
    ex.step(mapper, {"links": []}, _scan(time.monotonic() - 1.0))
    assert sent == [(0.3, 0.1), (0.0, 0.0)] and ex.status.startswith("paused: the newest mapped scan")
    ex.step(mapper, {"links": []}, _scan(time.monotonic() - 1.0))
    assert len(sent) == 2  # stopped once, not on every late scan


def test_a_silent_exploration_stops_the_robot_once():
    ex, sent = _exploring(_Explorer())
    mapper = SimpleNamespace(current=1, pose=(0.0, 0.0, 0.0), asrs={})
    ex.step(mapper, {}, _scan(time.monotonic()))
    ex.check(time.monotonic())
    ex.check(time.monotonic() + 1.0)
    ex.check(time.monotonic() + 2.0)
    assert sent == [(0.3, 0.1), (0.0, 0.0)] and ex.active and ex.status.startswith("paused: no command")


def test_exploration_ends_when_the_pioneer_cannot_be_driven():
    from service.mapper_worker import Exploration

    def refuse(v, w):
        raise ConnectionError("the Pioneer is not connected")

    ex = Exploration(refuse, lambda: False, period=0.0)
    ex.start()
    ex.explorer = _Explorer()
    ex.step(SimpleNamespace(current=1, pose=(0.0, 0.0, 0.0), asrs={}), {}, _scan(time.monotonic()))
    assert not ex.active and ex.status.startswith("stopped: cannot drive")


def test_no_velocity_follows_a_stop_and_done_stops_the_robot():
    ex, sent = _exploring(_Explorer(done_after=2))
    mapper = SimpleNamespace(current=1, pose=(0.0, 0.0, 0.0), asrs={})
    ex.step(mapper, {}, _scan(time.monotonic()))
    ex.step(mapper, {}, _scan(time.monotonic()))
    assert sent == [(0.3, 0.1), (0.3, 0.1), (0.0, 0.0)] and not ex.active and ex.status.startswith("done")
    ex.start()
    assert ex.stop("cmd/stop") and not ex.stop("again")
    ex.step(mapper, {}, _scan(time.monotonic()))
    assert len(sent) == 3 and ex.status == "stopped: cmd/stop"


class HangingMapper(FakeMapper):
    """Takes ``hang`` seconds over its third scan, as a wedged computation would."""

    def __init__(self, hang: float):
        super().__init__()
        self.hang = hang

    def add_scan(self, scan):
        if self.n == 2:
            time.sleep(self.hang)
        return super().add_scan(scan)


def test_a_wedged_mapper_stops_the_watchdog_pings(tmp_path):
    with Bench(tmp_path, new_mapper=lambda c, doc: HangingMapper(2.5)) as b:
        b.messages("READY=1")
        pings = []
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            if b.notify.recv(4096) == b"WATCHDOG=1":
                pings.append(time.monotonic())
        gaps = np.diff(pings)
        # Pinged every 0.1 s (WATCHDOG_USEC 0.2 s) except while the mapper was stuck beyond 1 s.
        assert gaps.max() > 1.0 and np.median(gaps) < 0.15
