"""The mapper thread (:class:`MapperWorker`): the pose at each scan's time, ``Mapper.add_odometry``
+ ``add_scan``, the store's commit, then publication on Zenoh (commit first: what was published
survives a crash); and the explorer driving the robot from that thread (:class:`Exploration`).
Poses in ASR frames and the global frame as the mapper defines them (m, rad); times are
``time.monotonic()`` seconds of this host."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from mapper.se2 import Pose
from mapper.types import Odometry, Scan
from service.buffers import DropOldest, OdometryBuffer, Rate
from service.bus import Bus
from service.config import Config
from service.store import SCHEMA as MAP_SCHEMA
from service.store import MapStore

log = logging.getLogger(__name__)


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
        self.document: dict[str, Any] = self._stamp(mapper.document())
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
        doc = self._stamp(self.mapper.document())
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
        pose = (0.0, 0.0, 0.0)
        if resume and resume[0] == doc["asrs"][-1]["id"]:
            pose = tuple(resume[1])
        log.info("continuing the stored map: %d ASRs, robot at %s in ASR %s", len(doc["asrs"]),
                 pose, doc["asrs"][-1]["id"])
        return Mapper.from_document(doc, params, pose)
    return Mapper(params)
