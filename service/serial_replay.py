"""Serial replay: a recorded CARMEN log played through the device emulators and the whole service.

The direct replay (:mod:`service.replay`) hands the log's readings to the mapper. This one plays the
log's odometry as the SIPs of an emulated Pioneer 2DX (:class:`pioneer.playback.PlaybackBody`) and
its scans as the 0xB0 telegrams of an emulated LMS200 (:class:`laser.playback.PlaybackLMS2xx`), both
on pty pairs, and runs the live service (:class:`service.pipeline.Service`, what ``asrmap run``
runs, with a generated :class:`~service.config.Config`) on them: drivers, time alignment, mapper
thread, SQLite store, Zenoh on loopback. At the end it writes what the direct replay writes.

Time (the simulator's mechanism, :class:`service.sim.simulator.WorldDevices`): every component keeps
the host's ``time.monotonic()`` (the drivers stamp readings with it) and the *recording* runs
``speed`` times faster: recorded time = ``t0 + (host time - wall0) * speed`` (:class:`PlaybackClock`),
the SIP cycle is 100 ms / ``speed`` and each scan is due at its recorded time on that clock. Both
emulators read the one clock, so odometry and scans stay in step as recorded; the service sees
host times, and the map document's times are mapped back to recorded time at the end.

What the protocols change (the tolerance of :func:`compare`): positions are sent in 0.84 mm units
(±0.42 mm per axis), headings in 2π/4096 rad (±0.77 mrad), ranges in 1 mm (or 1 cm) units (±0.5 mm,
or ±5 mm). What the service's timing adds on top: the pose at a scan is interpolated (or, before the
next SIP arrives, extrapolated) between 100 ms SIPs instead of the log's own samples, and the
telegrams' arrival dates carry the threads' latency × ``speed``. :func:`compare` reports both.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import math
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mapper.params import MapperParams
from mapper.se2 import compose, inverse
from mapper.types import Odometry, Scan
from service.carmen import NO_RETURN_M, mapper_inputs
from service.config import LASER_BAUDS, PIONEER_BAUDS
from service.evaluate import Track, evaluate, is_corrected, read_truth, rebuild_corrected, truth_from_log
from service.replay import ReplayResult, params_for_log

log = logging.getLogger(__name__)

SIP_UNIT_M = 0.84e-3  # P2DX DistConvFactor: metres per SIP position unit
THETA_UNIT_RAD = 2 * math.pi / 4096  # AngleConvFactor: radians per SIP heading unit
LMS_MODE5_MAX = 32767  # range codes of measuring mode 5 (the reader's default): 32.767 m in mm


# --- the recording ------------------------------------------------------------------------------------


@dataclass
class Recording:
    """A log's readings as arrays: odometry samples ``odo_t`` (s) / ``odo`` (N x 3: m, m, rad,
    odometry frame) and scans ``scan_t`` (s) / ``scans`` (metres per beam, beam 0 at ``angle_min``,
    ``angle_increment`` apart, readings >= ``no_return`` are no return), each in time order."""

    odo_t: np.ndarray
    odo: np.ndarray
    scan_t: np.ndarray
    scans: list[np.ndarray]
    angle_min: float
    angle_increment: float
    no_return: float = NO_RETURN_M
    truth: Track | None = None
    mode: str = "raw"

    @classmethod
    def from_inputs(cls, inputs: Iterable[Odometry | Scan], **kw) -> Recording:
        odo_t, odo, scan_t, scans = [], [], [], []
        amin = inc = None
        no_return = NO_RETURN_M
        for r in inputs:
            if isinstance(r, Odometry):
                odo_t.append(r.t)
                odo.append(r.pose)
            else:
                scan_t.append(r.t)
                scans.append(np.asarray(r.ranges, dtype=np.float32))
                amin, inc, no_return = r.angle_min, r.angle_increment, r.max_range
        if not scans or not odo_t:
            raise ValueError("the log has no scans or no odometry to play back")
        # A device sends in time order; a log need not be in it (the Intel log has scans up to 0.9 s
        # out of order), so both paths get the readings sorted by time, stably.
        io, js = np.argsort(odo_t, kind="stable"), np.argsort(scan_t, kind="stable")
        return cls(np.asarray(odo_t)[io], np.asarray(odo, dtype=np.float64).reshape(-1, 3)[io],
                   np.asarray(scan_t)[js], [scans[j] for j in js], float(amin), float(inc), float(no_return),
                   **kw)

    @classmethod
    def from_log(cls, path: str | Path, logged_poses: bool = False, start: float | None = None,
                 duration: float | None = None) -> Recording:
        """The readings :func:`service.replay.replay` would feed (rebuilt odometry for a corrected log
        unless ``logged_poses``), optionally only ``duration`` s from ``start`` s after the first."""
        truth = None
        mode = "raw"
        if not logged_poses and is_corrected(path):
            inputs, truth = rebuild_corrected(path)
            mode = "corrected, rebuilt odometry"
        else:
            inputs = mapper_inputs(path, "flaser")
            if logged_poses:
                mode = "logged poses"
                truth = truth_from_log(path) if is_corrected(path) else None
        rec = cls.from_inputs(inputs, truth=truth, mode=mode)
        return rec.window(start, duration) if start is not None or duration is not None else rec

    def window(self, start: float | None, duration: float | None) -> Recording:
        """The readings from ``start`` s after the first scan for ``duration`` s (None: to the end)."""
        t0 = float(self.scan_t[0]) + (start or 0.0)
        t1 = math.inf if duration is None else t0 + duration
        ks = (self.scan_t >= t0) & (self.scan_t <= t1)
        # Odometry one sample either side, so every kept scan lies inside the odometry.
        ko = np.flatnonzero((self.odo_t >= t0) & (self.odo_t <= t1))
        lo = max(0, int(ko[0]) - 1) if len(ko) else 0
        hi = min(len(self.odo_t), int(ko[-1]) + 2) if len(ko) else len(self.odo_t)
        return dataclasses.replace(self, odo_t=self.odo_t[lo:hi], odo=self.odo[lo:hi], scan_t=self.scan_t[ks],
                                   scans=[s for s, k in zip(self.scans, ks, strict=True) if k])

    def inputs(self) -> Iterator[Odometry | Scan]:
        """The readings in time order (odometry first at equal times), for the direct replay."""
        items = [(float(t), 0, i) for i, t in enumerate(self.odo_t)]
        items += [(float(t), 1, i) for i, t in enumerate(self.scan_t)]
        # Stable on log order for equal keys: duplicated log times keep their order.
        for t, kind, i in sorted(items, key=lambda x: (x[0], x[1])):
            if kind == 0:
                yield Odometry(t, *map(float, self.odo[i]))
            else:
                yield Scan(t, self.scans[i], self.angle_min, self.angle_increment, self.no_return)

    @property
    def start(self) -> float:
        return float(min(self.odo_t[0], self.scan_t[0]))

    @property
    def end(self) -> float:
        return float(max(self.odo_t[-1], self.scan_t[-1]))

    @property
    def fov_deg(self) -> int:
        """The sweep's field of view (degrees, rounded): 180 for every shared log."""
        return round(math.degrees(self.angle_increment * (len(self.scans[0]) - 1)))

    @property
    def resolution_deg(self) -> float:
        """The LMS variant's resolution nearest to the beam spacing (1, 0.5 or 0.25 degrees)."""
        step = math.degrees(self.angle_increment)
        return min((1.0, 0.5, 0.25), key=lambda r: abs(r - step))

    def max_valid_range(self) -> float:
        return max((float(np.max(s[s < self.no_return], initial=0.0)) for s in self.scans), default=0.0)

    def units(self) -> str:
        """"mm" when every return fits measuring mode 5's 32.767 m in mm, else "cm"."""
        return "mm" if self.max_valid_range() < LMS_MODE5_MAX * 1e-3 else "cm"

    def max_scan_gap(self) -> float:
        return float(np.max(np.diff(self.scan_t), initial=0.0))


# --- one clock for both devices -----------------------------------------------------------------------


class PlaybackClock:
    """Recorded time from host time: ``t0 + (time.monotonic() - wall0) * speed`` once :meth:`start`
    has set ``wall0``; ``t0`` before that (the robot waits at the first pose, the laser is silent)."""

    def __init__(self, t0: float, speed: float) -> None:
        if not speed > 0:
            raise ValueError(f"the speed factor must be positive, not {speed}")
        self.t0 = float(t0)
        self.speed = float(speed)
        self.wall0: float | None = None

    def start(self) -> None:
        self.wall0 = time.monotonic()

    def now(self) -> float:
        """Recorded seconds now."""
        return self.t0 if self.wall0 is None else self.to_log(time.monotonic())

    def to_log(self, wall: float) -> float:
        """A host ``time.monotonic()`` as recorded time (s)."""
        return self.t0 + (wall - (self.wall0 or 0.0)) * self.speed

    def to_wall(self, t: float) -> float | None:
        """A recorded time as host time, None before :meth:`start`."""
        return None if self.wall0 is None else self.wall0 + (t - self.t0) / self.speed


# --- speed limits ---------------------------------------------------------------------------------------

LASER_BAUD = max(LASER_BAUDS)  # the fastest LMS2xx line (RS-422): what lets the replay run fastest
#: The fastest P2OS host line (HOSTBAUD 4). A SIP reaches the host one transfer time after it was
#: sampled: 32 ms at 9600 baud, after the 500 kbaud scan of that instant (its first ray 14 ms
#: before), so the service would extrapolate every scan's odometry (over 0.2-0.3 s of recorded
#: time at 8x). At 115200 a SIP takes 2.7 ms, and the SIPs around each scan are in.
PIONEER_BAUD = max(PIONEER_BAUDS)


def line_speed_limit(rec: Recording, baud: int = LASER_BAUD) -> float:
    """The largest speed factor at which the laser line carries the log's scans at their median
    spacing: median scan interval (s) / one 0xB0 telegram's transmission time at ``baud``."""
    from laser.timing import b0_size, transmit_time

    dt = np.diff(rec.scan_t)
    dt = dt[dt > 0]
    median = float(np.median(dt)) if len(dt) else 0.1
    return median / transmit_time(b0_size(len(rec.scans[0])), baud)


# --- the run ---------------------------------------------------------------------------------------------


class _RecordingMapper:
    """The mapper, recording what the service gave it (odometry on the host clock, events) and the
    seconds it spent; everything else is the mapper's."""

    def __init__(self, mapper: Any) -> None:
        self.mapper = mapper
        self.odometry: list[tuple[float, tuple[float, float, float]]] = []
        self.events: collections.Counter = collections.Counter()
        self.seconds = 0.0
        self.scans = 0
        self.scan_inputs: list[Scan] = []

    def add_odometry(self, odo: Odometry):
        self.odometry.append((odo.t, odo.pose))
        tic = time.perf_counter()
        out = list(self.mapper.add_odometry(odo) or ())
        self.seconds += time.perf_counter() - tic
        return out

    def add_scan(self, scan: Scan):
        tic = time.perf_counter()
        out = list(self.mapper.add_scan(scan) or ())
        self.seconds += time.perf_counter() - tic
        self.scans += 1
        self.scan_inputs.append(scan)
        for e in out:
            self.events[e.kind] += 1
        return out

    def flush(self):
        tic = time.perf_counter()
        out = list(self.mapper.flush() or ())
        self.seconds += time.perf_counter() - tic
        for e in out:
            self.events[e.kind] += 1
        return out

    def __getattr__(self, name: str):
        return getattr(self.mapper, name)


@dataclass
class SerialReplayResult(ReplayResult):
    """A :class:`~service.replay.ReplayResult` (times in the log's time) plus what the serial path did.

    ``speed``: recorded seconds per host second; ``wall_seconds``: host time from the start of playback
    to the last scan mapped; ``counters``: scans sent / skipped by the line / dropped by the pipeline /
    mapped, SIPs sent, and the emulators' and drivers' counters; ``motors_stopped``: the emulated robot
    ended with its motors disabled and no velocity set; ``profile``: host seconds by stage.
    """

    speed: float = 1.0
    wall_seconds: float = 0.0
    counters: dict = field(default_factory=dict)
    motors_stopped: bool = False
    profile: dict = field(default_factory=dict)
    scan_inputs: list = field(default_factory=list)

    @property
    def dropped(self) -> int:
        """Scans of the log that never reached the mapper (line skips, pipeline drops, no odometry)."""
        c = self.counters
        lost = max(0, c.get("scans_sent", 0) - c.get("scans_received", 0))
        return (c.get("scans_skipped", 0) + c.get("scans_dropped", 0) + c.get("scans_without_odometry", 0)
                + lost)


def _config(pioneer_port: str, laser_port: str, state_dir: str, rec: Recording, speed: float,
            robot: str, zenoh_listen: tuple[str, ...], laser_baud: int):
    from service import config as cfgmod

    cfg = cfgmod.Config()
    # A log may pause (the Intel log has 1.8 s between two scans): at the log's pace that is no fault.
    silence = min(60.0, max(0.5, rec.max_scan_gap() / speed + 0.5))
    return dataclasses.replace(
        cfg,
        robot=dataclasses.replace(cfg.robot, name=robot),
        pioneer=dataclasses.replace(cfg.pioneer, port=pioneer_port, baudrate=PIONEER_BAUD),
        laser=dataclasses.replace(cfg.laser, port=laser_port, baudrate=laser_baud, fov=rec.fov_deg,
                                  resolution=rec.resolution_deg, units=rec.units()),
        zenoh=dataclasses.replace(cfg.zenoh, listen=zenoh_listen),
        store=dataclasses.replace(cfg.store, state_dir=state_dir),
        # Every scan is kept waiting rather than dropped while the mapper catches up on a burst.
        pipeline=dataclasses.replace(cfg.pipeline, scan_queue=64),
        watchdog=dataclasses.replace(cfg.watchdog, scan_timeout=silence,
                                     odometry_timeout=max(cfg.watchdog.odometry_timeout, 5.0 / speed)),
    )


def serial_replay(
    path: str | Path | None,
    params: MapperParams | None = None,
    truth: str | Path | Track | None = None,
    logged_poses: bool = False,
    speed: float | str = 1.0,
    *,
    recording: Recording | None = None,
    rate_limit: bool = True,
    laser_baud: int = LASER_BAUD,
    state_dir: str | None = None,
    zenoh_listen: tuple[str, ...] | None = None,
    robot: str = "pioneer",
    progress: Callable[[int, int, float], None] | None = None,
    timeout: float | None = None,
) -> SerialReplayResult:
    """Play ``path`` (or ``recording``) through both emulators and the service; see the module docstring.

    ``speed``: recorded seconds per host second, or ``"max"`` for :func:`line_speed_limit` (the
    fastest the 500 kbaud laser line carries the log). ``rate_limit=False`` sends scans as fast as
    they are due whatever the baud. ``state_dir``: the service's store directory (temporary by
    default); ``zenoh_listen``: its endpoints (default: a free loopback TCP port). ``progress(scans
    mapped, scans in the log, mapper s)``. ``timeout``: host seconds before giving up (default: the
    log's duration / speed + 60 s). Raises ``RuntimeError`` when the service fails, ``TimeoutError``
    when it never connects.
    """
    from laser.playback import PlaybackLMS2xx
    from pioneer.emulator import PioneerEmulator
    from pioneer.playback import PlaybackBody, PoseTrack
    from serialport.ptys import open_pty
    from service.bench.service import free_port
    from service.pipeline import Service

    rec = recording or Recording.from_log(path, logged_poses)
    given_truth = read_truth(truth) if truth else None  # a bad truth log is refused before the run
    if params is None:
        params = params_for_log(path) if path is not None else MapperParams()
    if speed == "max":
        speed = line_speed_limit(rec, laser_baud) if rate_limit else 10 * line_speed_limit(rec, laser_baud)
    speed = float(speed)
    clock = PlaybackClock(rec.start, speed)
    track = PoseTrack(rec.odo_t, rec.odo[:, 0], rec.odo[:, 1], rec.odo[:, 2])
    tmp = None if state_dir else tempfile.TemporaryDirectory(prefix="asrmap-serial-replay-")
    state = state_dir or tmp.name  # type: ignore[union-attr]
    listen = zenoh_listen if zenoh_listen is not None else (f"tcp/127.0.0.1:{free_port()}",)
    stop = threading.Event()
    result: dict[str, Any] = {}
    holder: dict[str, _RecordingMapper] = {}
    timeout = timeout if timeout is not None else (rec.end - rec.start) / speed + 60.0

    def new_mapper(cfg, doc):
        holder["m"] = _RecordingMapper(_new(params))
        return holder["m"]

    with contextlib.ExitStack() as st:
        if tmp is not None:
            st.callback(tmp.cleanup)
        pio_pty, las_pty = st.enter_context(open_pty()), st.enter_context(open_pty())
        body = PlaybackBody(track, clock.now)
        pio = PioneerEmulator(pio_pty.master, body=body, sip_cycle=0.1 / speed)
        las = PlaybackLMS2xx(las_pty.master, rec.scan_t, rec.scans, clock.to_wall, fov=rec.fov_deg,
                             resolution=rec.resolution_deg, no_return=rec.no_return, rate_limit=rate_limit,
                             boot_time=0.05)
        st.enter_context(pio.start())
        st.enter_context(las.start())
        cfg = _config(pio_pty.path, las_pty.path, state, rec, speed, robot, listen, laser_baud)
        service = Service(cfg, open_laser=_laser_opener(cfg), new_mapper=new_mapper)

        def serve() -> None:
            try:
                result["status"] = service.run(stop)
            except BaseException as exc:  # reported below, on the caller's thread
                result["error"] = exc
                stop.set()

        thread = threading.Thread(target=serve, name="asrmap-service", daemon=True)
        thread.start()
        wall_end = time.monotonic()
        try:
            _wait_connected(service, pio, las, stop, deadline=time.monotonic() + 30.0)
            clock.start()
            log.info("serial replay: %d scans over %.1f s at %.1fx", len(rec.scans), rec.end - rec.start,
                     speed)
            wall_end = _wait_played(service, las, rec, stop, holder, progress, clock.wall0 + timeout)
        finally:
            stop.set()
            thread.join(10.0)
        if "error" in result:
            raise RuntimeError(f"the service failed: {result['error']}") from result["error"]
        motors_stopped = (not pio.motors_enabled and body.commanded == (0.0, 0.0)
                          and pio.state == "waiting")
        counters = _counters(service, pio, las, holder.get("m"))
    m = holder.get("m")
    if m is None:
        raise RuntimeError("the service never built its mapper")
    to_log = clock.to_log
    doc = m.mapper.document()
    doc = _retime(doc, to_log)
    odometry = Track([to_log(t) for t, _ in m.odometry], [p for _, p in m.odometry])
    wall = wall_end - (clock.wall0 or wall_end)
    res = SerialReplayResult(
        mapper=m.mapper, document=doc, scans=m.scans,
        log_seconds=float(rec.scan_t[-1] - rec.scan_t[0]), mapper_seconds=m.seconds, events=m.events,
        odometry=odometry, mode=f"{rec.mode}, through serial at {speed:.1f}x", speed=speed,
        wall_seconds=wall, counters=counters, motors_stopped=motors_stopped,
        profile={"wall": wall, "mapper": m.seconds},
    )
    res.scan_inputs = [dataclasses.replace(sc, t=to_log(sc.t)) for sc in m.scan_inputs]
    truth_track = given_truth if given_truth is not None else rec.truth
    if truth_track is not None and len(truth_track) and len(odometry):
        gm = m.mapper.globalmap
        entered = {k: gm.topology.entered_from(k) for k in gm.asrs}
        res.evaluation = evaluate(doc, truth_track, odometry, entered, gm.odometry_origin)
    return res


def _new(params: MapperParams):
    from mapper.mapper import Mapper

    return Mapper(params)


def _laser_opener(cfg):
    """``open_laser`` with a silence margin as long as the log's longest pause (see :func:`_config`)."""
    import laser
    from laser.reader import Timeouts

    margin = cfg.watchdog.scan_timeout

    def open_laser(_cfg):
        return laser.LMS2xx(cfg.laser.port, cfg.laser.baudrate, resolution=cfg.laser.resolution,
                            fov=cfg.laser.fov, units=cfg.laser.units, recover=False,
                            timeouts=Timeouts(scan_margin=margin))

    return open_laser


def _wait_connected(service, pio, las, stop: threading.Event, deadline: float) -> None:
    """Until the service has both devices up and the laser streams (the playback starts then)."""
    while not stop.is_set():
        if (service.pioneer.state == "ok" and service.laser.state == "ok" and pio.state == "open"
                and las.streaming and service.odometry.latest() is not None):
            return
        if time.monotonic() > deadline:
            raise TimeoutError(f"the service did not connect to the emulators within 30 s "
                               f"(pioneer {service.pioneer.state}, laser {service.laser.state})")
        time.sleep(0.005)


def _wait_played(service, las, rec: Recording, stop: threading.Event, holder: dict,
                 progress, deadline: float) -> float:
    """Until every scan was sent and has been mapped (or dropped); returns the host time then."""
    total = len(rec.scans)
    last_report = 0.0
    while not stop.is_set():
        w = service.worker
        done = w.counters["scans_mapped"] + w.counters["scans_without_odometry"] if w else 0
        # Every telegram written has been read, and handed to the mapper or dropped. (Counted on the
        # service's side: after the log the laser falls silent and the driver is reopened afresh.)
        settled = (las.finished and done + service.scans.dropped >= las.counters["scans_sent"]
                   and len(service.scans) == 0 and (w is None or w.busy_since is None))
        now = time.monotonic()
        if progress and now - last_report > 0.2:
            last_report = now
            m = holder.get("m")
            progress(done, total, m.seconds if m else 0.0)
        if settled:
            if progress:
                m = holder.get("m")
                progress(done, total, m.seconds if m else 0.0)
            return now
        if now > deadline:
            log.warning("serial replay: gave up waiting for the last scans (%d of %d mapped)", done, total)
            return now
        time.sleep(0.005)
    return time.monotonic()


def _counters(service, pio, las, m) -> dict:
    w = service.worker
    dev = service.laser.device
    return {
        "scans_in_log": len(las.times),
        "scans_sent": las.counters["scans_sent"],
        "scans_skipped": las.counters["scans_skipped"],
        "scans_received": (w.counters["scans_mapped"] + w.counters["scans_without_odometry"]
                           + service.scans.dropped) if w else 0,
        "scans_dropped": service.scans.dropped,
        "scans_mapped": w.counters["scans_mapped"] if w else 0,
        "scans_without_odometry": w.counters["scans_without_odometry"] if w else 0,
        "laser_bytes_lost": las.counters["bytes_lost"],
        "laser_late_max_s": las.counters["playback_late_max"],
        "sips_sent": pio.counters["sips_sent"],
        "pioneer_bytes_lost": pio.counters["bytes_lost"],
        "mapper_errors": w.counters["mapper_errors"] if w else 0,
        "laser_faults": service.laser.faults,
        "pioneer_faults": service.pioneer.faults,
        "laser_driver": dict(dev.counters) if dev is not None else {},
    }


def _retime(doc: dict, f: Callable[[float], float]) -> dict:
    from service.sim.simulator import _retime as retime  # one definition of which fields are times

    return retime(doc, f)


# --- agreement with the direct replay -------------------------------------------------------------------


def quantisation_tolerance(max_range: float, units: str = "mm") -> dict[str, float]:
    """The largest differences the protocols' quantisation alone can make (metres, radians).

    - SIP position: rounded to 0.84 mm units, ±0.42 mm per axis, so a pose is off by at most
      0.42·√2 = 0.59 mm; a relative pose (two poses) by twice that, 1.19 mm.
    - SIP heading: rounded to 2π/4096 rad, ±0.77 mrad; relative: 1.53 mrad.
    - Range: rounded to 1 mm (±0.5 mm) or 1 cm (±5 mm).
    - A scan point at range r moves by position + r·heading + range: at ``max_range`` that bounds
      how far any boundary vertex of an ASR (built from points) can move between the two paths.
    """
    pos = 2 * math.hypot(SIP_UNIT_M / 2, SIP_UNIT_M / 2)
    head = 2 * THETA_UNIT_RAD / 2
    rng = (1e-3 if units == "mm" else 1e-2) / 2
    return {"position": pos, "heading": head, "range": rng, "point": pos + max_range * head + rng}


@dataclass
class Agreement:
    """How two map documents of the same log differ. ``same_structure``: equal ASR ids, exits per
    ASR, links and accepted cycles; the rest are the largest differences (m, rad) between matching
    ASRs: ``origin`` (relative to ASR 1's origin), ``centre``, ``created`` (s)."""

    same_structure: bool
    asrs: tuple[int, int]
    links: tuple[int, int]
    cycles: tuple[int, int]
    origin_position: float = 0.0
    origin_heading: float = 0.0
    centre: float = 0.0
    created: float = 0.0
    problems: list[str] = field(default_factory=list)


def compare(a: dict, b: dict) -> Agreement:
    """Compare map documents ``a`` (e.g. direct) and ``b`` (serial); see :class:`Agreement`."""
    problems = []
    ia = {x["id"]: x for x in a["asrs"]}
    ib = {x["id"]: x for x in b["asrs"]}
    if set(ia) != set(ib):
        problems.append(f"ASR ids differ: {sorted(set(ia) ^ set(ib))}")
    links_a = {(k["from"], k["to"], bool(k.get("oneway"))) for k in a["links"]}
    links_b = {(k["from"], k["to"], bool(k.get("oneway"))) for k in b["links"]}
    if links_a != links_b:
        problems.append(f"links differ: {sorted(links_a ^ links_b)}")
    cyc_a = {(c["asr"], c.get("matches"), c["accepted"]) for c in a["cycles"]}
    cyc_b = {(c["asr"], c.get("matches"), c["accepted"]) for c in b["cycles"]}
    if {c for c in cyc_a if c[2]} != {c for c in cyc_b if c[2]}:
        problems.append(f"accepted cycles differ: {sorted(cyc_a ^ cyc_b)}")
    ag = Agreement(not problems, (len(ia), len(ib)), (len(links_a), len(links_b)),
                   (sum(c["accepted"] for c in a["cycles"]), sum(c["accepted"] for c in b["cycles"])),
                   problems=problems)
    common = sorted(set(ia) & set(ib))
    if not common:
        return ag
    ra, rb = inverse(tuple(ia[common[0]]["origin"])), inverse(tuple(ib[common[0]]["origin"]))
    for k in common:
        xa, xb = ia[k], ib[k]
        if len(xa.get("exits", ())) != len(xb.get("exits", ())):
            ag.problems.append(f"ASR {k}: {len(xa['exits'])} exits vs {len(xb['exits'])}")
            ag.same_structure = False
        oa, ob = compose(ra, tuple(xa["origin"])), compose(rb, tuple(xb["origin"]))
        ag.origin_position = max(ag.origin_position, math.hypot(oa[0] - ob[0], oa[1] - ob[1]))
        ag.origin_heading = max(ag.origin_heading, abs(math.remainder(oa[2] - ob[2], 2 * math.pi)))
        ag.centre = max(ag.centre, math.dist(xa["centre"], xb["centre"]))
        ag.created = max(ag.created, abs(xa["created"] - xb["created"]))
    return ag
