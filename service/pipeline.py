"""The live service: the Pioneer and the laser through their drivers, the mapper on its own thread,
the map store, Zenoh, systemd.

Threads and what each may wait on:

- the drivers' reader threads: serial only. Their callbacks append odometry to an
  :class:`OdometryBuffer` and scans to a :class:`DropOldest` queue, and return: serial reading never
  waits for the mapper; when the mapper falls behind, the oldest waiting scan is dropped and counted.
- one :class:`Link` thread per device: opens the driver (handshakes can take seconds), watches for
  silence, reports ``fault``/``recovered`` and reopens the device without restarting the service.
- the mapper thread (:class:`MapperWorker`): pose at each scan's time, ``Mapper.add_odometry`` +
  ``add_scan``, store commit, then publication (commit first: what was published survives a crash).
- the main thread (:meth:`Service.run`): READY/WATCHDOG/STOPPING, status, safety. It pings the
  systemd watchdog only while the mapper thread is not stuck, so a wedged mapper gets restarted.

Clocks: every timestamp is ``time.monotonic()`` seconds of this host (drivers stamp readings with it).
Frames: odometry in the odometry frame (continuous across Pioneer reconnections, see
:class:`OdometryBuffer`), poses in ASR frames and the global frame as the mapper defines them.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from mapper.se2 import Pose, compose, interpolate, inverse
from mapper.types import Odometry, Scan
from service.bus import Bus, CommandRefused
from service.config import Config
from service.motion import MotionGate, stop_on_thread_crash
from service.notify import Notifier
from service.store import SCHEMA as MAP_SCHEMA
from service.store import MapStore

log = logging.getLogger(__name__)


# --- time alignment ---------------------------------------------------------------------------------


class OdometryBuffer:
    """Recent odometry (t s, x, y m, theta rad; odometry frame) and the pose at any time.

    :meth:`at` interpolates between the samples around ``t``; past the newest sample it
    extrapolates at the last measured velocity for at most ``max_extrapolation`` seconds (a scan
    usually ends between two SIPs; waiting for the next SIP would add up to 100 ms of latency).
    That velocity is measured over at least ``velocity_baseline`` seconds (from the newest sample back
    to the newest one that much older): SIPs completed by one late read arrive milliseconds apart,
    and a velocity taken between two of them would throw the extrapolated pose metres away.

    Odometry restarts at (0, 0, 0) whenever P2OS is reopened; :meth:`new_session` makes the next
    sample continue from the last pose so the mapper sees one continuous odometry frame.
    """

    def __init__(self, history: float = 5.0, max_extrapolation: float = 0.25,
                 velocity_baseline: float = 0.05):
        self.history = history
        self.max_extrapolation = max_extrapolation
        self.velocity_baseline = velocity_baseline
        self._t: list[float] = []
        self._p: list[Pose] = []
        self._offset: Pose = (0.0, 0.0, 0.0)
        self._rebase = False
        self._lock = threading.Lock()

    def new_session(self) -> None:
        """The next sample starts a new odometry session (the driver was reopened)."""
        with self._lock:
            self._rebase = True

    def add(self, t: float, x: float, y: float, theta: float) -> Pose:
        """Record a raw sample; returns it in the continuous frame. Samples going back in time are
        ignored (a reordered callback must not bend the trajectory)."""
        with self._lock:
            raw = (float(x), float(y), float(theta))
            if self._rebase and self._p:
                self._offset = compose(self._p[-1], inverse(raw))
            self._rebase = False
            pose = compose(self._offset, raw)
            if self._t and t <= self._t[-1]:
                return pose
            self._t.append(float(t))
            self._p.append(pose)
            if self._t[0] < t - self.history and len(self._t) > 2:
                cut = bisect.bisect_left(self._t, t - self.history)
                del self._t[: min(cut, len(self._t) - 2)], self._p[: min(cut, len(self._p) - 2)]
            return pose

    def latest(self) -> tuple[float, Pose] | None:
        with self._lock:
            return (self._t[-1], self._p[-1]) if self._t else None

    def at(self, t: float) -> Pose | None:
        """The pose at time ``t`` (s), or None before any odometry."""
        with self._lock:
            n = len(self._t)
            if n == 0:
                return None
            if n == 1 or t <= self._t[0]:
                return self._p[0] if t <= self._t[0] else self._p[-1]
            i = bisect.bisect_left(self._t, t)
            if i >= n:  # after the newest sample: extrapolate over the velocity baseline
                t1 = self._t[-1]
                t = min(t, t1 + self.max_extrapolation)
                j = max(0, min(bisect.bisect_right(self._t, t1 - self.velocity_baseline) - 1, n - 2))
                return interpolate(self._p[j], self._p[-1], (t - self._t[j]) / (t1 - self._t[j]))
            t0, t1 = self._t[i - 1], self._t[i]
            return interpolate(self._p[i - 1], self._p[i], (t - t0) / (t1 - t0))


class DropOldest:
    """A bounded FIFO between a producer that must never wait and a slower consumer."""

    def __init__(self, maxlen: int):
        self._d: deque = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, item: Any) -> None:
        with self._cond:
            if len(self._d) >= self._maxlen:
                self._d.popleft()
                self.dropped += 1
            self._d.append(item)
            self._cond.notify()

    def get(self, timeout: float) -> Any | None:
        with self._cond:
            if not self._d:
                self._cond.wait(timeout)
            return self._d.popleft() if self._d else None

    def __len__(self) -> int:
        return len(self._d)


class Rate:
    """Events per second over the last ``window`` seconds."""

    def __init__(self, window: float = 2.0):
        self._times: deque[float] = deque()
        self.window = window

    def tick(self, now: float | None = None) -> None:
        self._times.append(time.monotonic() if now is None else now)

    def hz(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        while self._times and self._times[0] < now - self.window:
            self._times.popleft()
        return len(self._times) / self.window


# --- one serial device, kept open ----------------------------------------------------------------------


class Link:
    """Keeps one device open: ``open_device()`` builds the driver, ``attach(device)`` hooks its
    callbacks (which call :meth:`touch`). No data for ``stale_after`` seconds (or an open that
    fails) is a fault: the device is closed and reopened after ``retry`` seconds, doubling after
    each failed open up to 2 s, until it answers.

    ``on_change(name, state, reason)`` runs on this link's thread at ``fault`` and at ``recovered``;
    states: ``connecting`` (never up yet), ``ok``, ``fault``.
    """

    def __init__(self, name: str, open_device: Callable[[], Any], attach: Callable[[Any], None],
                 stale_after: float, retry: float, on_change: Callable[[str, str, str], None]):
        self.name = name
        self._open = open_device
        self._attach = attach
        self.stale_after = stale_after
        self.retry = retry
        self._on_change = on_change
        self.state = "connecting"
        self.reason = ""
        self.faults = 0
        self.recoveries = 0
        self.device: Any = None
        self.rate = Rate()
        self._last = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"link-{name}", daemon=True)

    def start(self) -> Link:
        self._thread.start()
        return self

    def touch(self, device: Any) -> bool:
        """Data arrived from ``device``; False if it is not the current device (a stale callback)."""
        if device is not self.device:
            return False
        self._last = time.monotonic()
        self.rate.tick(self._last)
        return True

    def _set(self, state: str, reason: str) -> None:
        before, self.state, self.reason = self.state, state, reason
        if state == "fault" and before != "fault":
            self.faults += 1
            log.warning("%s: fault: %s", self.name, reason)
            self._on_change(self.name, "fault", reason)
        elif state == "ok" and before == "fault":
            self.recoveries += 1
            log.warning("%s: recovered", self.name)
            self._on_change(self.name, "recovered", "")
        elif state == "ok":
            log.info("%s: connected", self.name)

    def _run(self) -> None:
        failures = 0
        while not self._stop.is_set():
            try:
                dev = self._open()
            except Exception as exc:  # every failure to open is a fault to report, then retry
                self._set("fault", f"cannot open: {exc}")
                # Back off (doubling, at most 2 s): a device that is gone for minutes is not
                # hammered, and one that returns is found again within 2 s.
                self._stop.wait(min(self.retry * 2 ** failures, max(self.retry, 2.0)))
                failures += 1
                continue
            failures = 0
            self._last = time.monotonic()
            self.device = dev
            try:
                self._attach(dev)
                self._set("ok", "")
                while not self._stop.wait(0.02):
                    silent = time.monotonic() - self._last
                    if silent > self.stale_after:
                        self._set("fault", f"no data for {silent:.2f} s")
                        break
            except Exception as exc:  # a bug in a callback must not end the watching of a device
                log.exception("%s: link supervision failed", self.name)
                self.state, self.reason = "fault", f"internal error: {exc}"
                self._stop.wait(self.retry)
            finally:
                self.device = None
                self._close(dev)

    def _close(self, dev: Any) -> None:
        try:
            dev.close()
        except Exception as exc:  # a vanished device may fail to say goodbye; it is closed anyway
            log.debug("%s: close failed: %s", self.name, exc)

    def stop(self, timeout: float | None = 1.5) -> None:
        """Stop watching and close the device (the driver stops the device's output); with
        ``timeout=None`` only ask, and :meth:`join` later (several links close in parallel)."""
        self._stop.set()
        if timeout is not None:
            self.join(timeout)

    def join(self, timeout: float) -> None:
        if self._thread.ident is not None:
            self._thread.join(timeout)

    def snapshot(self) -> dict[str, Any]:
        dev = self.device
        counters = getattr(dev, "counters", None) if dev is not None else None
        return {"link": self.state, "reason": self.reason or None, "faults": self.faults,
                "recoveries": self.recoveries, "rate": round(self.rate.hz(), 2),
                "driver": getattr(dev, "link_state", None), "counters": dict(counters or {})}


# --- exploration (cmd/explore) ---------------------------------------------------------------------------


class Exploration:
    """The explorer of :mod:`service.explore` driving the robot from the mapper thread.

    :meth:`step` runs after each mapped scan: it commands at most every ``period`` seconds (P2OS at
    9600 baud carries ~50 velocity commands a second, and the robot's control loop runs at 10 Hz),
    and only from a fresh scan (``max_age`` seconds): a mapper that fell behind must not steer by
    what the laser saw long ago, so the robot is stopped instead. :meth:`check`, from the main
    loop, stops the robot when no command went out for ``silence`` seconds (a mapper that hangs:
    the driver's keep-alive would otherwise let the last command run on). :meth:`stop` holds the
    same lock as a step, so no velocity command follows a stop.
    """

    def __init__(self, send: Callable[[float, float], Any], stalled: Callable[[], bool],
                 period: float = 0.1, max_age: float = 0.3, silence: float = 0.5):
        self._send = send
        self._stalled = stalled
        self.period = period
        self.max_age = max_age
        self.silence = silence
        self.active = False
        self.status = "idle"
        self.explorer: Any = None
        self._next = 0.0
        self._last_sent = 0.0
        self._halted = False
        self._lock = threading.Lock()

    def start(self) -> None:
        from service.explore import Explorer

        with self._lock:
            if not self.active:
                self.explorer = Explorer()
                self.active, self.status = True, "starting"
                self._last_sent, self._halted = time.monotonic(), False
                log.info("exploration started")

    def stop(self, why: str) -> bool:
        """End exploring (the caller stops the robot); True if it was active."""
        with self._lock:
            was, self.active = self.active, False
            if was:
                self.status = f"stopped: {why}"
                log.info("exploration stopped: %s", why)
            return was

    def _command(self, v: float, w: float) -> None:
        try:
            self._send(v, w)
        except Exception as exc:  # the Pioneer went away between the check and the write
            self.active, self.status = False, f"stopped: cannot drive ({exc})"
            log.warning("exploration stopped: cannot drive: %s", exc)
            return
        self._last_sent, self._halted = time.monotonic(), v == 0.0 and w == 0.0

    def check(self, now: float) -> None:
        """Stop the robot once if exploring and no command went out for ``silence`` seconds."""
        with self._lock:
            if self.active and not self._halted and now - self._last_sent > self.silence:
                self.status = f"paused: no command for {now - self._last_sent:.1f} s (the mapper is behind)"
                log.warning("exploration paused: %s", self.status)
                self._command(0.0, 0.0)

    def step(self, mapper: Any, document: dict[str, Any], scan: Any) -> None:
        from service.explore import MapView, links_of, scan_points

        with self._lock:
            now = time.monotonic()
            if not self.active or now < self._next:
                return
            self._next = now + self.period
            if now - scan.t > self.max_age:
                self.status = f"paused: the newest mapped scan is {now - scan.t:.2f} s old"
                if not self._halted:
                    self._command(0.0, 0.0)
                return
            if mapper.current is None:
                self.status = "waiting for the first ASR"
                return
            ex = self.explorer
            pts = scan_points(np.asarray(scan.ranges, float), np.asarray(scan.angles, float),
                              float(getattr(scan, "max_range", 8.0)), ex.p)
            view = MapView(mapper.current, mapper.pose, mapper.asrs, links_of(document.get("links", ())))
            cmd = ex.step(view, pts, scan.t, self._stalled())
            self.status = cmd.status
            self._command(cmd.v, cmd.w)
            if cmd.done and self.active:
                self.active, self.status = False, "done: every exit explored"
                self._command(0.0, 0.0)
                log.info("exploration done")


# --- the mapper thread ------------------------------------------------------------------------------------


def mapper_scan(scan: Any):
    """A driver's scan (``t`` s, ``ranges`` m, ``angles`` rad, laser frame) as the mapper's ``Scan``."""
    ranges = np.asarray(scan.ranges, dtype=float)
    angles = np.asarray(scan.angles, dtype=float)
    inc = float(angles[1] - angles[0]) if len(angles) > 1 else 0.0
    max_range = float(getattr(scan, "max_range", np.nanmax(ranges) if len(ranges) else 0.0))
    return Scan(float(scan.t), ranges, float(angles[0]) if len(angles) else 0.0, inc, max_range)


def pose_report(mapper: Any, t: float, odometry: Pose) -> dict[str, Any]:
    """The ``asrmap/pose/1`` body: ``t`` (s, the scan's time), ``asr`` (current ASR id), ``pose`` (m,
    m, rad in that ASR's frame), ``global`` (in the global frame), ``odometry`` (odometry frame)."""
    asr = getattr(mapper, "current", None)
    pose = glob = None
    if asr is not None:
        pose, glob = mapper.pose, mapper.global_pose
    return {"t": t, "asr": asr, "pose": _round(pose), "global": _round(glob), "odometry": _round(odometry)}


def _round(p: Pose | None) -> list[float] | None:
    return None if p is None else [round(float(v), 6) for v in p]


class MapperWorker:
    """Feeds the mapper from the scan queue on its own thread; commits, then publishes."""

    def __init__(self, mapper: Any, store: MapStore, bus: Bus | None, scans: DropOldest,
                 odometry: OdometryBuffer, robot: str, pose_period: float, publish_scans: bool):
        self.mapper = mapper
        self.store = store
        self.bus = bus
        self.scans = scans
        self.odometry = odometry
        self.robot = robot
        self.pose_period = pose_period
        self.publish_scans = publish_scans
        self.busy_since: float | None = None
        self.mapped = Rate()
        self.counters = {"scans_mapped": 0, "scans_without_odometry": 0, "events": 0, "mapper_errors": 0}
        #: (wall s, mapper-thread CPU s, scan stamp s, processing s, latency s) per mapped scan, for
        #: the status's real-time factor, CPU share and end-to-end latency (see :meth:`timing`).
        self.timings: deque[tuple[float, float, float, float, float]] = deque(maxlen=50)
        self.document: dict[str, Any] = self._stamp(document_of(mapper))
        self.last_pose: dict[str, Any] | None = None
        self.exploration: Exploration | None = None
        self._next_pose = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mapper", daemon=True)

    def _stamp(self, doc: dict[str, Any]) -> dict[str, Any]:
        return {**doc, "schema": MAP_SCHEMA, "robot": self.robot}

    def start(self) -> MapperWorker:
        self._thread.start()
        return self

    def stop(self, timeout: float = 0.5) -> bool:
        """Stop after the reading in hand; False if the mapper is still busy after ``timeout`` s."""
        self._stop.set()
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            scan = self.scans.get(0.1)
            if scan is None:
                continue
            self.busy_since = time.monotonic()
            try:
                self.process(scan)
                done = time.monotonic()
                # Latency: the scan's first ray to its map update committed and published.
                self.timings.append((done, time.thread_time(), float(scan.t), done - self.busy_since,
                                     done - float(scan.t)))
            except Exception:  # one bad reading must not end the mapping
                self.counters["mapper_errors"] += 1
                log.exception("the mapper failed on the scan at t=%.3f", getattr(scan, "t", math.nan))
            finally:
                self.busy_since = None
        try:  # the last viewpoint's view waits for a next scan (see "Pipelining" in mapper.mapper)
            events = list(self.mapper.flush())
            if events:
                self.commit_and_publish(events)
        except Exception:
            self.counters["mapper_errors"] += 1
            log.exception("the mapper failed on its last view")

    def process(self, scan: Any) -> list[Any]:
        """Map one driver scan; returns the mapper's events."""
        odo = self.odometry.at(scan.t)
        if odo is None:
            self.counters["scans_without_odometry"] += 1
            return []
        events = list(self.mapper.add_odometry(Odometry(scan.t, *odo)) or ())
        events += list(self.mapper.add_scan(mapper_scan(scan)) or ())
        self.counters["scans_mapped"] += 1
        self.mapped.tick()
        if events:
            self.commit_and_publish(events)
        bus = self.bus
        if bus is not None and self.publish_scans:
            ms = mapper_scan(scan)
            bus.publish_scan(ms.t, ms.ranges, ms.angle_min, ms.angle_increment, ms.max_range)
        now = time.monotonic()
        if now >= self._next_pose:
            self._next_pose = now + self.pose_period
            self.last_pose = pose_report(self.mapper, scan.t, odo)
            if self.last_pose["asr"] is not None:
                self.store.save_pose(self.last_pose["asr"], self.last_pose["pose"])
            if bus is not None:
                bus.publish_pose(self.last_pose)
        if self.exploration is not None and self.exploration.active:
            self.exploration.step(self.mapper, self.document, scan)
        return events

    def timing(self) -> dict[str, float | None]:
        """Over the last scans mapped: ``latency`` (s, first ray to published; mean and max),
        ``realtime_factor`` (seconds of scans per second of mapping: above 1 keeps up) and
        ``cpu_share`` (the mapper thread's CPU seconds per wall second: 1.0 is one core)."""
        t = list(self.timings)
        if len(t) < 2:
            return {"latency": None, "latency_max": None, "realtime_factor": None, "cpu_share": None}
        busy = sum(r[3] for r in t[1:])
        wall = t[-1][0] - t[0][0]
        return {"latency": round(sum(r[4] for r in t) / len(t), 4),
                "latency_max": round(max(r[4] for r in t), 4),
                "realtime_factor": round((t[-1][2] - t[0][2]) / busy, 2) if busy > 0 else None,
                "cpu_share": round((t[-1][1] - t[0][1]) / wall, 3) if wall > 0 else None}

    def commit_and_publish(self, events: list[Any]) -> None:
        """Store first, then Zenoh: a subscriber never sees what a crash could lose."""
        doc = self._stamp(document_of(self.mapper))
        synced = self.store.sync(doc)
        self.document = doc
        self.counters["events"] += len(events)
        if self.bus is None:
            return
        by_id = {int(a["id"]): a for a in doc.get("asrs", ())}
        for i in synced.asrs:
            self.bus.publish_asr(by_id[i])
        for e in events:
            d = e.to_dict()
            if d.get("event") != "asr_updated":  # answered by the asr/<id> put above
                self.bus.publish_event(d)


# --- the service ------------------------------------------------------------------------------------------


def make_mapper(cfg: Config, doc: dict[str, Any] | None):
    """A new mapper, or the stored map continued (``Mapper.from_document``).

    ``doc["resume"]`` (put there by :class:`Service` from the store) is where the robot was: ASR id
    and pose in its frame. The mapper resumes in the document's last ASR, so the pose is used when
    that is the ASR the robot was in (a restart after a crash: the robot has not moved).
    """
    from mapper.mapper import Mapper

    params = cfg.mapper_params()
    resume = (doc or {}).pop("resume", None)
    if doc and doc.get("asrs"):
        if hasattr(Mapper, "from_document"):
            pose = (0.0, 0.0, 0.0)
            if resume and resume[0] == doc["asrs"][-1]["id"]:
                pose = tuple(resume[1])
            log.info("continuing the stored map: %d ASRs, robot at %s in ASR %s", len(doc["asrs"]),
                     pose, doc["asrs"][-1]["id"])
            return Mapper.from_document(doc, params, pose)
        log.warning("this mapper cannot continue a stored map (no Mapper.from_document): starting a new one")
    return Mapper(params)


def document_of(mapper: Any) -> dict[str, Any]:
    """The mapper's ``asrmap/map/1`` document (its ASRs alone while it has no ``document()``)."""
    if hasattr(mapper, "document"):
        return mapper.document()
    from mapper.document import to_document

    return to_document([mapper.asrs[k] for k in sorted(mapper.asrs)], [], [])


def open_pioneer(cfg: Config):
    import pioneer

    # reconnect=False: as for the laser, the Link reopens a lost Pioneer (odometry stays continuous
    # through OdometryBuffer.new_session).
    params = getattr(pioneer, cfg.pioneer.model.upper())
    return pioneer.Pioneer(cfg.pioneer.port, cfg.pioneer.baudrate, params, reconnect=False)


def open_laser(cfg: Config):
    import laser

    # recover=False: the driver reports a lost link and stops; the Link reopens it (one policy, one
    # place, and it also covers a port that vanished and came back under the same udev name).
    return laser.LMS2xx(cfg.laser.port, cfg.laser.baudrate, resolution=cfg.laser.resolution,
                        fov=cfg.laser.fov, units=cfg.laser.units, recover=False)


class Service:
    """``asrmap run``: everything above wired together; :meth:`run` until ``stop`` is set."""

    def __init__(self, cfg: Config, *, notifier: Notifier | None = None,
                 open_pioneer: Callable[[Config], Any] = open_pioneer,
                 open_laser: Callable[[Config], Any] = open_laser,
                 new_mapper: Callable[[Config, dict | None], Any] = make_mapper):
        self.cfg = cfg
        self._new_mapper = new_mapper
        self.notifier = notifier or Notifier()
        self._open_pioneer = open_pioneer
        self._open_laser = open_laser
        self.odometry = OdometryBuffer(cfg.pipeline.odometry_history)
        self.scans = DropOldest(cfg.pipeline.scan_queue)
        self.started = time.monotonic()
        self.battery: float | None = None
        self._blind_stop_sent = False
        self._ready = False
        self.bus: Bus | None = None
        self.worker: MapperWorker | None = None
        wd = cfg.watchdog
        self.pioneer = Link("pioneer", lambda: self._open_pioneer(cfg), self._attach_pioneer,
                            wd.odometry_timeout, wd.reconnect_interval, self._on_link_change)
        self.laser = Link("laser", lambda: self._open_laser(cfg), self._attach_laser,
                          wd.scan_timeout, wd.reconnect_interval, self._on_link_change)
        # Every velocity goes through the gate: it expires 0.5 s after its source's last command.
        self.motion = MotionGate(self._drive, self._halt, max_age=0.5)
        self.exploration = Exploration(lambda v, w: self.motion.command(v, w, "explore"), self._stalled)
        self.skew: deque[float] = deque(maxlen=50)  # s: scan first ray minus the newest SIP stamp

    # --- device callbacks (driver threads): record and return --------------------------------------

    def _attach_pioneer(self, dev: Any) -> None:
        self.odometry.new_session()

        def on_odometry(o: Any) -> None:
            if self.pioneer.touch(dev):
                self.odometry.add(o.t, o.x, o.y, o.theta)
                battery = getattr(o, "battery", None)
                if battery is not None:
                    self.battery = float(battery)

        dev.on_odometry(on_odometry)

    def _attach_laser(self, dev: Any) -> None:
        def on_scan(scan: Any) -> None:
            if self.laser.touch(dev):
                newest = self.odometry.latest()
                if newest is not None:
                    self.skew.append(float(scan.t) - newest[0])
                self.scans.put(scan)

        dev.on_scan(on_scan)

    def _on_link_change(self, device: str, what: str, reason: str) -> None:
        body = {"event": what, "t": time.monotonic(), "device": device}
        if reason:
            body["reason"] = reason
        if what == "fault":
            self.exploration.stop(f"{device} fault")
            if device == "laser":
                self.stop_robot("the laser is blind")
        if self.bus is not None:
            self.bus.publish_event(body)

    # --- safety and commands -------------------------------------------------------------------------

    def stop_robot(self, why: str) -> bool:
        """Command zero velocity now (``why`` is kept as the last stop's reason); False when the
        Pioneer is not connected (P2OS stops its motors by itself when the host falls silent)."""
        ok = self.motion.stop(why)
        if ok:
            log.info("robot stopped: %s", why)
        return ok

    def _halt(self) -> bool:
        dev = self.pioneer.device
        return dev is not None and dev.stop() is not False

    def _drive(self, v: float, w: float) -> None:
        dev = self.pioneer.device
        if dev is None:
            raise CommandRefused("the Pioneer is not connected")
        dev.set_velocity(v, w)

    def _stalled(self) -> bool:
        dev = self.pioneer.device
        sip = getattr(getattr(dev, "odometry", None), "sip", None)
        return bool(getattr(sip, "left_stall", False) or getattr(sip, "right_stall", False))

    def _command(self, name: str, params: dict[str, str]) -> dict[str, Any]:
        if name == "stop":
            self.exploration.stop("cmd/stop")
            if not self.stop_robot("cmd/stop"):
                raise CommandRefused("the Pioneer is not connected; P2OS stops its motors on its own")
            return {"stopped": True}
        if name == "explore":
            down = [link.name for link in (self.pioneer, self.laser) if link.state != "ok"]
            if down:
                raise CommandRefused(f"cannot explore: {' and '.join(down)} not connected")
            self.exploration.start()
            return {"exploring": True}
        raise CommandRefused(f"unknown command {name}")

    # --- status ---------------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        w = self.worker
        busy = w.busy_since if w else None
        return {
            "t": time.monotonic(),
            "robot": self.cfg.robot.name,
            "uptime": round(time.monotonic() - self.started, 3),
            "pioneer": self.pioneer.snapshot(),
            "laser": self.laser.snapshot(),
            "rates": {"scans": round(self.laser.rate.hz(), 2), "sips": round(self.pioneer.rate.hz(), 2),
                      "mapped": round(w.mapped.hz(), 2) if w else 0.0},
            "battery": self.battery,
            "dropped_scans": self.scans.dropped,
            "scan_queue": len(self.scans),
            "mapper": dict(w.counters) if w else {},
            "mapper_busy": round(time.monotonic() - busy, 3) if busy else 0.0,
            "asrs": len(w.document.get("asrs", ())) if w else 0,
            "explore": {"active": self.exploration.active, "status": self.exploration.status},
            "bus": dict(self.bus.counters) if self.bus else {},
            "motors": self._motors(),
            "timing": {**(w.timing() if w else {}), **self._skew()},
            "last_stop": None if self.motion.last_stop is None else {
                "t": round(self.motion.last_stop[0], 3), "reason": self.motion.last_stop[1]},
            "waiting_for": self.waiting_for(),
        }

    def _motors(self) -> dict[str, Any]:
        """The Pioneer's motors as its latest SIP reports them, and the driver's alerts (e-stop,
        motors disabled, battery low, each with its remedy)."""
        dev = self.pioneer.device
        sip = getattr(getattr(dev, "odometry", None), "sip", None)
        return {"enabled": None if sip is None else bool(sip.motors_enabled),
                "e_stop": None if sip is None else bool(sip.e_stop),
                "alerts": list(getattr(dev, "alerts", ()) or ())}

    def _skew(self) -> dict[str, float | None]:
        """Scan first-ray stamp minus the newest SIP stamp when the scan arrived (s): about half a
        SIP cycle on average when both clocks agree; far beyond 0.1 s means a stamp is wrong."""
        s = list(self.skew)
        if not s:
            return {"skew": None, "skew_max": None}
        return {"skew": round(sum(s) / len(s), 4), "skew_max": round(max(s, key=abs), 4)}

    def waiting_for(self) -> str | None:
        """What the service still waits for before it can map (None when both devices are up)."""
        down = [link for link in (self.pioneer, self.laser) if link.state != "ok"]
        if not down:
            return None
        port = {"pioneer": self.cfg.pioneer.port, "laser": self.cfg.laser.port}
        return "; ".join(f"the {link.name} on {port[link.name]}"
                         + (f" ({link.reason})" if link.reason else "") for link in down)

    def _status_text(self) -> str:
        waiting = self.waiting_for()
        if waiting is not None and not self._ready:
            budget = self.cfg.watchdog.startup_timeout
            waited = time.monotonic() - self.started
            return f"waiting for {waiting}" + (f" ({waited:.0f} s of {budget:.0f} s)" if budget else "")
        return (f"pioneer {self.pioneer.state}, laser {self.laser.state}, "
                f"{len(self.worker.document.get('asrs', ())) if self.worker else 0} ASRs, "
                f"{self.scans.dropped} scans dropped")

    # --- lifecycle ------------------------------------------------------------------------------------

    def run(self, stop: threading.Event) -> int:
        """Run until ``stop`` is set; returns the exit status (0). Raises ``BusError``/``OSError``
        for what the operator must fix (a busy port, an unwritable state directory)."""
        cfg = self.cfg
        # Zenoh first: a busy port or a bad zenoh file fails before anything else is touched.
        self.bus = Bus(cfg.robot.name, cfg.zenoh, lambda: self.worker.document if self.worker else None,
                       self._command)
        try:
            store = MapStore(cfg.store_path)
        except BaseException:
            self.bus.close()
            raise
        try:
            stored = store.load()
            if stored:
                stored["resume"] = store.load_pose()
            mapper = self._new_mapper(cfg, stored)
            if stored and stored.get("asrs") and not document_of(mapper).get("asrs"):
                store.archive("not-continued")
            self.worker = MapperWorker(mapper, store, None, self.scans, self.odometry, cfg.robot.name,
                                       1.0 / cfg.publish.pose_rate, cfg.publish.scans)
        except BaseException:
            store.close()
            self.bus.close()
            raise
        self.worker.bus = self.bus
        self.worker.exploration = self.exploration
        restore = stop_on_thread_crash(self.stop_robot)
        try:
            self.motion.start()
            self.pioneer.start()
            self.laser.start()
            self.worker.start()
            return self._loop(stop)
        finally:
            try:
                self._shutdown(store)
            finally:
                restore()

    def _loop(self, stop: threading.Event) -> int:
        """The main loop; returns the exit status: 0 when stopped, 1 when the devices were not both
        up within ``watchdog.startup_timeout`` (systemd's Restart=on-failure then tries again)."""
        cfg, n = self.cfg, self.notifier
        interval = n.watchdog_interval
        next_ping = next_status = time.monotonic()
        n.status("waiting for the Pioneer and the laser")  # then every status period: which, and why
        while not stop.wait(0.02):
            now = time.monotonic()
            budget = cfg.watchdog.startup_timeout
            if not self._ready and budget and now - self.started > budget:
                log.error("gave up after %.0f s (watchdog.startup_timeout) waiting for %s", budget,
                          self.waiting_for())
                n.status(f"gave up waiting for {self.waiting_for()}")
                return 1
            if not self._ready and self.pioneer.state == "ok" and self.laser.state == "ok":
                self._ready = True
                n.ready(self._status_text())
                log.info("ready: mapping as %s", cfg.robot.name)
            if self.laser.state != "ok" and self.pioneer.state == "ok":
                if not self._blind_stop_sent:
                    self._blind_stop_sent = self.stop_robot("the laser is blind")
            else:
                self._blind_stop_sent = False
            self.exploration.check(now)
            busy = self.worker.busy_since
            stalled = busy is not None and now - busy > cfg.watchdog.mapper_stall
            if interval and now >= next_ping and not stalled:
                n.watchdog()
                next_ping = now + interval / 2
            if now >= next_status:
                next_status = now + 1.0 / cfg.publish.status_rate
                self.bus.publish_status(self.status())
                if stalled:
                    log.error("the mapper has been busy for %.1f s: no watchdog pings", now - busy)
                n.status(self._status_text())
        return 0

    def _shutdown(self, store: MapStore) -> None:
        """Motors first, then the laser's output, then Zenoh; everything bounded (< 2 s)."""
        log.info("stopping")
        self.notifier.stopping("stopping")
        self.exploration.stop("shutting down")
        self.motion.close("shutting down")  # zero velocity, and no gate thread left to send more
        self.laser.stop(None)
        self.pioneer.stop(None)
        self.laser.join(1.2)
        self.pioneer.join(1.2)
        finished = self.worker.stop(0.5)
        try:
            self.bus.close()
        finally:
            if finished:
                store.close()
            else:
                log.warning("the mapper was still busy at shutdown; its last reading is not stored")
        log.info("stopped")
