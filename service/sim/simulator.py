"""Simulated runs: a Pioneer 2DX with an LMS200 exploring a :class:`~service.sim.world.World`.

Two ways to run, with the same robot (:class:`SimRobot`: the pioneer package's
:class:`~pioneer.physics.DiffDrive` kinematics and odometry error, this package's collision body
and ray caster), the same explorer and the same summary:

- :class:`DirectSim`: one thread, a simulated clock, the mapper called in-process. Deterministic
  for a seed and as fast as the computer allows; what the tests use.
- :class:`StackSim`: the real thing in one process. The emulators speak P2OS and LMS2xx on pty
  pairs; :class:`service.pipeline.Service` reads them through the drivers exactly as on the robot,
  maps, stores and publishes on Zenoh; the explorer reads the mapper and drives the robot through
  the Pioneer driver.

Time in :class:`StackSim`: every component keeps the host's ``time.monotonic()`` (the drivers stamp
readings with it), and the *world* runs ``speed`` times faster: the Pioneer's SIP cycle and the
laser's scan period are divided by ``speed`` and the body integrates ``speed`` x the elapsed wall
time, so per simulated second there are as many SIPs and scans as on the robot, and every velocity
in a P2OS command or SIP keeps its real meaning. The service sees a robot that moves ``speed``
times faster than its commands, which it never checks. ``speed`` is bounded by how fast the mapper
keeps up (the pipeline drops the oldest scans when it cannot; the summary counts them).

Frames: the world frame is the world file's; the emulated odometry starts at (0, 0, 0) at the
world's start pose, as P2OS does at power-on. Units: metres, radians, seconds.
"""

from __future__ import annotations

import bisect
import contextlib
import logging
import math
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mapper.se2 import Pose, compose, inverse
from mapper.types import Odometry, Scan
from pioneer.physics import DiffDrive, OdometryError
from service.config import LASER_BAUDS, PIONEER_BAUDS
from service.evaluate import Track, describe_false, evaluate
from service.explore import Command, ExploreParams, Explorer, MapView, links_of, scan_points
from service.sim import loops
from service.sim.physics import Body
from service.sim.raycast import LMS_MAX_RANGE, RayCaster
from service.sim.world import World

log = logging.getLogger(__name__)

#: The default odometry error: 1 % long on distance, 0.5 % short on rotation, 0.5°/m heading drift:
#: about what a Pioneer 2DX on a lab floor shows, enough that the global map visibly drifts.
DEFAULT_ODOMETRY_ERROR = OdometryError(distance_scale=1.01, heading_scale=0.995,
                                       drift_per_m=math.radians(0.5))


@dataclass(frozen=True)
class SimParams:
    """One simulated run. Times in simulated seconds.

    ``sip_cycle``: P2OS SIP cycle (0.1 s); ``scan_period``: seconds between scans (the LMS200 at
    38400 baud, 181 values: 96.9 ms); ``resolution``: degrees between beams; ``sigma``: range noise
    (m); ``odometry_error``: the encoders' error; ``footprint``: ``"rect"`` or ``"circle"``;
    ``duration``: stop after this long (None: when exploration is done, capped at ``max_duration``);
    ``command_latency``: simulated seconds from a scan's sampling to the robot acting on the command
    the explorer computed from it (the stepped simulation only; the whole stack has its own: the
    scan's transmission, the mapper, the planning and the P2OS command, 0.15-0.35 s at 10x).
    """

    sip_cycle: float = 0.1
    scan_period: float = 0.0969
    resolution: float = 1.0
    sigma: float = 0.01
    odometry_error: OdometryError = DEFAULT_ODOMETRY_ERROR
    footprint: str = "rect"
    seed: int = 0
    explore: bool = True
    duration: float | None = None
    max_duration: float = 3600.0
    explore_params: ExploreParams = field(default_factory=ExploreParams)
    command_latency: float = 0.0


class SimRobot:
    """The robot in the world: DiffDrive kinematics (true and odometry poses in the emulator's
    frame, starting at (0, 0, 0)), a collision :class:`Body` in the world frame behind its motion
    hook, and a :class:`RayCaster` for the laser. ``truth`` is the true pose track (world frame)
    and ``odometry`` the odometry track, both on the caller's clock."""

    def __init__(self, world: World, params: SimParams, clock: Callable[[], float]) -> None:
        self.world = world
        self.params = params
        self.clock = clock
        self.body = Body(world, footprint=params.footprint, record_every=0.0)
        self.caster = RayCaster(world, sigma=params.sigma, seed=params.seed)
        self.drive = DiffDrive(odometry_error=params.odometry_error, motion_hook=self.motion_hook)
        self.stalls = 0
        self.truth = Track([clock()], [world.start])
        self._lock = threading.Lock()

    def motion_hook(self, old: Pose, new: Pose) -> Pose | None:
        """The pioneer's motion hook: the world's say on a step from ``old`` to ``new`` (emulator frame)."""
        reached, stalled = self.body.move(self.body.world_pose(new), self.clock())
        with self._lock:
            self.truth.append(self.clock(), reached)
        if not stalled:
            return new  # exactly as wished: the drive compares poses to detect a block
        self.stalls += 1
        return self.body.emulator_pose(reached)

    def true_pose_at(self, t: float) -> Pose:
        """The true pose (world frame) at time ``t`` of :attr:`clock`."""
        with self._lock:
            return self.truth.at(t)

    def angles(self) -> np.ndarray:
        """Beam angles (rad, laser frame) of a 180° scan at the configured resolution."""
        n = round(180.0 / self.params.resolution) + 1
        return np.radians(np.linspace(-90.0, 90.0, n))

    def ranges(self, t: float, angles: np.ndarray) -> np.ndarray:
        """A scan (m) taken at time ``t`` (simulated s), beams at ``angles`` (rad, laser frame); a beam
        that meets nothing reads the caster's ``max_range``, the no-return value the stepped
        simulation hands the mapper. The emulated LMS takes :meth:`RayCaster.source` instead."""
        return self.caster.scan(self.true_pose_at(t), angles)


class LockedMapper:
    """The mapper behind a lock, so the explorer reads a consistent state while the mapper thread
    writes. Records what the summary needs: every event, which ASR each was entered from, and
    every crossing ``(t, from ASR, to ASR)`` (the mapper's clock, s); and :attr:`scan`, the scan
    last mapped, whose pose (the current ASR's frame) :meth:`view` gives."""

    def __init__(self, mapper: Any) -> None:
        self.mapper = mapper
        self.lock = threading.RLock()
        self.events: list[Any] = []
        self.entered_from: dict[int, int | None] = {}
        self.crossings: list[tuple[float, int, int]] = []
        self._links: list = []
        self._dirty = True
        self.scan: Scan | None = None

    def add_odometry(self, odo: Odometry):
        with self.lock:
            return self.mapper.add_odometry(odo)

    def add_scan(self, scan: Scan):
        with self.lock:
            events = self._record(list(self.mapper.add_scan(scan) or ()))
            self.scan = scan
            return events

    def flush(self):
        """The events of the view still waiting (see "Pipelining" in mapper.mapper)."""
        with self.lock:
            return self._record(list(self.mapper.flush() or ()))

    def _record(self, events: list[Any]) -> list[Any]:
        for e in events:
            if getattr(e, "kind", "") == "asr_created":
                self.entered_from[int(e.asr)] = getattr(e, "entered_from", None)
            elif getattr(e, "kind", "") == "exit_crossed":
                self.crossings.append((float(e.t), int(e.from_asr), int(e.to_asr)))
            if getattr(e, "kind", "") != "asr_updated":
                self.events.append(e)
        if events:
            self._dirty = True
        return events

    def __getattr__(self, name: str):
        return getattr(self.mapper, name)

    def document(self) -> dict:
        with self.lock:
            return map_document(self.mapper)

    def view(self, copy: bool = False) -> MapView:
        """The explorer's view (call with :attr:`lock` held); ``copy``: of the ASR table, to use
        after releasing the lock (the records themselves are shared)."""
        m = self.mapper
        if self._dirty:
            self._dirty = False
            self._links = links_of(_links_of_mapper(m))
        return MapView(m.current, m.pose, dict(m.asrs) if copy else m.asrs, list(self._links))


def _links_of_mapper(m: Any) -> list:
    for path in ("links", "topology.links", "globalmap.topology.links", "global_map.topology.links"):
        obj = m
        for part in path.split("."):
            obj = getattr(obj, part, None)
            if obj is None:
                break
        if obj is not None:
            return list(obj)
    if hasattr(m, "document"):
        return list(m.document().get("links", []))
    return []


def new_mapper(params: Any = None):
    """The mapper with ``params`` (default: :class:`mapper.params.MapperParams`, a P2DX's laser offset)."""
    try:
        from mapper import Mapper
    except ImportError:  # the package does not export it (yet): the module does
        from mapper.mapper import Mapper
    return Mapper(params) if params is not None else Mapper()


# --- the summary ------------------------------------------------------------------------------------------


@dataclass
class Summary:
    """What a run achieved, from the map and from ground truth. Distances in m, times in s."""

    world: str
    sim_time: float
    wall_time: float
    finished: bool
    asrs: int
    exits: int
    exits_unexplored: int
    cycles: int
    true_cycles: int
    false_cycles: int
    revisits: int
    revisits_missed: int
    distance: float
    contacts: int
    stuck: int
    regions_visited: list[str]
    regions_missed: list[str]
    scans: int = 0
    scans_dropped: int = 0
    #: Each false closure with its two true centre depths (:attr:`service.evaluate.Evaluation.false_depths`).
    false_depths: tuple = ()
    #: Exits the explorer tried and gave up in its last round (stuck, blocked, leading back), left
    #: unexplored when it declared exploration complete: "complete" then means nothing was left
    #: that it could reach, not that nothing was left.
    exits_given_up: int = 0
    #: The world's loops (:mod:`service.sim.loops`): its holes, the independent loops the robot's
    #: true path drove, and how many of those the map's true cycle closures closed.
    holes: int = 0
    loops_driven: int = 0
    loops_closed: int = 0
    #: Pushes: the contacts grouped into episodes, a contact more than ``PUSH_GAP`` s after the one
    #: before starting a new one. ``contacts`` counts blocked physics steps, so one push the robot
    #: takes a while to stop counts many times (more in the whole stack, which hears of the stall
    #: through a SIP, than in the stepped simulation).
    pushes: int = 0
    #: Where the robot ended wedged (world frame, m), if it did: in its last ``WEDGED_TIME`` s it
    #: moved less than ``WEDGED_DISTANCE`` and touched something. An exploration that ends so has
    #: given up its last goals because the robot could not move, not because nothing was left.
    wedged: tuple[float, float] | None = None

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else math.inf

    def lines(self) -> list[str]:
        regions = len(self.regions_visited) + len(self.regions_missed)
        out = [
            f"world {self.world}: {'exploration complete' if self.finished else 'stopped before the end'}"
            + (f" ({self.exits_given_up} exits given up)" if self.exits_given_up else "") + " "
            f"after {self.sim_time:.0f} s simulated in {self.wall_time:.0f} s "
            f"({self.realtime_factor:.1f}x real time)",
            f"ASRs {self.asrs}, exits {self.exits} ({self.exits_unexplored} unexplored)",
            f"cycles detected {self.cycles}: {self.true_cycles} true, {self.false_cycles} false"
            + (f": {describe_false(self.false_depths)}" if self.false_depths else ""),
            f"revisits {self.revisits}, missed {self.revisits_missed}",
            f"loops driven {self.loops_driven} (the world has {self.holes} holes), "
            f"closed by the map {self.loops_closed}",
            f"distance driven {self.distance:.1f} m, contacts {self.contacts} ({self.pushes} pushes), "
            f"stuck {self.stuck}",
            f"regions entered {len(self.regions_visited)}/{regions}"
            + (f" (missed: {', '.join(self.regions_missed)})" if self.regions_missed else ""),
        ]
        if self.wedged is not None:
            x, y = self.wedged
            out.append(f"the robot ended wedged at ({x:.2f}, {y:.2f}) m: it moved less than "
                       f"{WEDGED_DISTANCE:g} m in its last {WEDGED_TIME:g} s, touching something")
        if self.scans:
            out.append(f"scans mapped {self.scans}, dropped {self.scans_dropped}")
        return out


WEDGED_TIME, WEDGED_DISTANCE = 60.0, 0.3  # s, m: see Summary.wedged
PUSH_GAP = 1.0  # s: see Summary.pushes


def pushes(contacts: list) -> int:
    """How many episodes the contacts (each with its time ``t``, s) make (see :attr:`Summary.pushes`)."""
    times = sorted(c.t for c in contacts)
    return sum(1 for k, t in enumerate(times) if k == 0 or t - times[k - 1] > PUSH_GAP)


def _wedged(truth: Track, contacts: list, end: float) -> tuple[float, float] | None:
    """The robot's last position (world frame) if it ended wedged (see :attr:`Summary.wedged`)."""
    if not len(truth) or end - truth.t[0] < WEDGED_TIME:
        return None
    i = bisect.bisect_left(truth.t, end - WEDGED_TIME)
    xy = np.array([p[:2] for p in truth.poses[i:]])
    if not len(xy) or not any(c.t >= end - WEDGED_TIME for c in contacts):
        return None
    if float(np.hypot(*(xy - xy[-1]).T).max()) >= WEDGED_DISTANCE:
        return None
    return float(xy[-1, 0]), float(xy[-1, 1])


def summarise(world: World, doc: dict, robot: SimRobot, odometry: Track, entered_from: dict,
              explorer: Explorer | None, sim_time: float, wall_time: float, finished: bool,
              crossings: list[tuple[float, int, int]] = ()) -> Summary:
    """Score the map document against the robot's ground truth (:func:`service.evaluate.evaluate`,
    :mod:`service.sim.loops`); ``crossings``: the mapper's exit crossings on the simulated clock
    (:attr:`LockedMapper.crossings`)."""
    with robot._lock:
        truth = Track(robot.truth.t, robot.truth.poses)
    asrs = doc.get("asrs", [])
    if asrs and len(truth) and len(odometry):
        ev = evaluate(doc, truth, odometry, entered_from, margin=math.inf)
        cycles, tp, fp, rev, det = ev.cycles, ev.true_positives, ev.false_positives, ev.revisits, ev.detected
        true_pairs, depths = ev.true_pairs, ev.false_depths
    else:
        cycles = tp = fp = rev = det = 0
        true_pairs = depths = ()
    holes, loops_driven, loops_closed = loops.count(world, doc, truth, odometry, list(crossings), true_pairs)
    exits = [e for a in asrs for e in a.get("exits", [])]
    visited = {world.region_of(p[0], p[1]) for p in truth.poses[:: max(1, len(truth) // 5000)]}
    visited |= {world.region_of(*truth.poses[-1][:2])}
    names = list(world.regions)
    return Summary(
        world=world.name, sim_time=sim_time, wall_time=wall_time, finished=finished,
        asrs=len(asrs), exits=len(exits), exits_unexplored=sum(e.get("to") is None for e in exits),
        cycles=cycles, true_cycles=tp, false_cycles=fp, revisits=rev, revisits_missed=rev - det,
        distance=robot.body.distance, contacts=len(robot.body.contacts), pushes=pushes(robot.body.contacts),
        stuck=explorer.counts["stuck"] if explorer else 0,
        exits_given_up=len(explorer.planner.memory.failed_exits) if explorer else 0,
        regions_visited=[n for n in names if n in visited],
        regions_missed=[n for n in names if n not in visited],
        false_depths=depths,
        holes=holes, loops_driven=loops_driven, loops_closed=loops_closed,
        wedged=_wedged(truth, robot.body.contacts, sim_time),
    )


def map_document(mapper: Any, robot_name: str = "pioneer") -> dict:
    """The ``asrmap/map/1`` document of ``mapper`` (``Mapper.document()``), stamped with the robot name."""
    if hasattr(mapper, "document"):
        doc = dict(mapper.document())
    else:  # a mapper without document(): its ASRs alone
        from mapper.document import to_document

        doc = to_document([mapper.asrs[k] for k in sorted(mapper.asrs)], [], [])
    doc.setdefault("schema", "asrmap/map/1")
    doc["robot"] = robot_name
    return doc


# --- one thread, simulated clock ------------------------------------------------------------------------


class DirectSim:
    """The robot, the mapper and the explorer stepped in turn on a simulated clock (see the module
    docstring). ``progress(sim_time, explorer_status, mapper)`` is called about once a simulated second.
    After :meth:`run`: ``document`` (the map, ``asrmap/map/1``) and ``final_pose`` (the robot's last
    pose as the service publishes it, ``asrmap/pose/1``: ``asr``, ``global`` in m, m, rad in the
    global frame, ...; None before the first ASR)."""

    def __init__(self, world: World, params: SimParams | None = None, mapper: Any = None,
                 progress: Callable[[float, str, Any], None] | None = None) -> None:
        self.world = world
        self.p = params or SimParams()
        self.t = 0.0
        self.robot = SimRobot(world, self.p, lambda: self.t)
        self.robot.drive.motors_enabled = True
        self.mapper = LockedMapper(mapper if mapper is not None else new_mapper())
        self.final_pose: dict[str, Any] | None = None
        self.explorer = Explorer(self.p.explore_params) if self.p.explore else None
        self.odometry = Track()
        self.progress = progress
        self.scans = 0
        self.command = Command(0.0, 0.0, "idle")

    def run(self) -> Summary:
        p = self.p
        limit = p.duration if p.duration is not None else p.max_duration
        angles = self.robot.angles()
        next_scan = 0.0
        next_progress = 0.0
        wall0 = time.perf_counter()
        finished = False
        # Commands on their way to the motors, each acted on from its time on (the next physics
        # step when command_latency is 0).
        pending: deque[tuple[float, Command]] = deque()
        while self.t < limit:
            self.t += p.sip_cycle
            while pending and pending[0][0] <= self.t + 1e-9:
                cmd = pending.popleft()[1]
                self.robot.drive.set_velocity(cmd.v)
                self.robot.drive.set_rotation(cmd.w)
            self.robot.drive.step(p.sip_cycle)
            odo = self.robot.drive.odometry_pose
            self.odometry.append(self.t, odo)
            self.mapper.add_odometry(Odometry(self.t, *odo))
            if self.t + 1e-9 < next_scan:
                continue
            next_scan += p.scan_period
            ranges = self.robot.ranges(self.t, angles)
            self.mapper.add_scan(Scan(self.t, ranges, float(angles[0]), float(angles[1] - angles[0]),
                                      LMS_MAX_RANGE))
            self.scans += 1
            if self.explorer is not None:
                pts = scan_points(ranges, angles, LMS_MAX_RANGE, self.explorer.p)
                stalled = self.robot.drive.left_stall or self.robot.drive.right_stall
                with self.mapper.lock:
                    self.command = self.explorer.step(self.mapper.view(), pts, self.t, stalled)
                pending.append((self.t + p.command_latency, self.command))
                if self.command.done and p.duration is None:
                    finished = True
                    break
            if self.progress is not None and self.t >= next_progress:
                next_progress = self.t + 1.0
                self.progress(self.t, self.command.status, self.mapper)
        self.mapper.flush()
        doc = map_document(self.mapper.mapper)
        s = summarise(self.world, doc, self.robot, self.odometry, self.mapper.entered_from, self.explorer,
                      self.t, time.perf_counter() - wall0, finished, self.mapper.crossings)
        s.scans = self.scans
        self.document = doc
        m = self.mapper.mapper
        if m.current is not None:
            from service.mapper_worker import pose_report  # the service's body; it brings in Zenoh

            self.final_pose = pose_report(m, self.t, self.robot.drive.odometry_pose)
        return s


# --- the whole stack on ptys ------------------------------------------------------------------------------


class _ScaledDrive(DiffDrive):
    """DiffDrive whose time runs ``speed`` times faster than the wall clock the emulator steps it with."""

    speed = 1.0

    def step(self, dt: float) -> None:
        super().step(dt * self.speed)


class WorldDevices:
    """Both emulated devices on pty pairs, seeing and moving in ``world``: a
    :class:`~pioneer.emulator.PioneerEmulator` whose body is the simulated robot and an
    :class:`~laser.emulator.LMS2xxEmulator` whose ranges are ray cast from the robot's true pose.

    ``speed``: simulated seconds per wall second; the SIP cycle and the scan period are divided by it
    and the body integrates ``speed`` x the wall time (module docstring). Attributes once started:
    ``pioneer_path``, ``laser_path`` (pty slaves for any client), ``robot`` (:class:`SimRobot`,
    ground truth), ``wall0`` (the host time of simulated time 0).
    """

    def __init__(self, world: World, params: SimParams | None = None, speed: float = 1.0) -> None:
        self.world = world
        self.p = params or SimParams()
        self.speed = float(speed)
        self.wall0 = time.monotonic()
        self.robot = SimRobot(world, self.p, self.sim_clock)
        drive = _ScaledDrive(odometry_error=self.p.odometry_error, motion_hook=self.robot.motion_hook)
        drive.speed = self.speed
        self.robot.drive = drive
        self._stack = contextlib.ExitStack()
        self.pioneer_path = self.laser_path = ""

    def sim_clock(self) -> float:
        """Simulated seconds since the start (wall time x speed)."""
        return self.to_sim(time.monotonic())

    def to_sim(self, t_wall: float) -> float:
        """A host ``time.monotonic()`` time as simulated time."""
        return (t_wall - self.wall0) * self.speed

    def start(self) -> WorldDevices:
        from laser.emulator import LMS2xxEmulator
        from pioneer.emulator import PioneerEmulator
        from serialport.ptys import open_pty

        speed, scan_period, robot = self.speed, self.p.scan_period, self.robot

        class _Laser(LMS2xxEmulator):
            def _period(self) -> float:  # the world's scan rate, scaled with the world's clock
                return scan_period / speed

        ranges = robot.caster.source(lambda t_wall: robot.true_pose_at(self.to_sim(t_wall)))

        st = self._stack
        pio_pty, las_pty = st.enter_context(open_pty()), st.enter_context(open_pty())
        pio = PioneerEmulator(pio_pty.master, body=robot.drive, sip_cycle=self.p.sip_cycle / speed)
        las = _Laser(las_pty.master, ranges, resolution=self.p.resolution, boot_time=0.05)
        self.wall0 = time.monotonic()
        st.enter_context(pio.start())
        st.enter_context(las.start())
        self.pioneer_path, self.laser_path = pio_pty.path, las_pty.path
        return self

    def stop(self) -> None:
        self._stack.close()

    def __enter__(self) -> WorldDevices:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class StackSim:
    """Emulators on ptys + :class:`service.pipeline.Service` + the explorer (see the module docstring).

    ``speed``: simulated seconds per wall second. ``state_dir``: where the service keeps its map
    store (a temporary directory by default; a simulation always starts a new map). Zenoh: the
    service's default ``[zenoh]`` configuration (or ``listen``: the endpoints to listen on), keys
    under ``asrmap/<robot_name>/``, so ``asrmap monitor --robot <robot_name>`` follows the run.
    After :meth:`run`: ``document`` and ``final_pose`` (the last ``asrmap/pose/1`` the service
    published), as :class:`DirectSim` has them.
    """

    def __init__(self, world: World, params: SimParams | None = None, *, speed: float = 1.0,
                 state_dir: str | None = None, robot_name: str = "pioneer",
                 progress: Callable[[float, str, Any], None] | None = None,
                 listen: tuple[str, ...] | None = None) -> None:
        self.world = world
        self.listen = listen
        self.final_pose: dict[str, Any] | None = None
        self.p = params or SimParams()
        self.speed = float(speed)
        self.robot_name = robot_name
        self.progress = progress
        self._tmp = None if state_dir else tempfile.TemporaryDirectory(prefix="asrmap-sim-")
        self.state_dir = state_dir or self._tmp.name  # type: ignore[union-attr]
        self.devices = WorldDevices(world, self.p, self.speed)
        self.robot = self.devices.robot
        self.explorer = Explorer(self.p.explore_params) if self.p.explore else None
        self.mapper: LockedMapper | None = None
        self.service = None
        self._user_stop = threading.Event()
        self.command = Command(0.0, 0.0, "idle")

    def request_stop(self) -> None:
        """End the run at the next explorer step (safe from a signal handler)."""
        self._user_stop.set()

    def sim_clock(self) -> float:
        """Simulated seconds since the start (wall time x speed)."""
        return self.devices.sim_clock()

    # -- wiring --------------------------------------------------------------------------------------
    def _config(self, pioneer_port: str, laser_port: str):
        from service import config as cfgmod

        cfg = cfgmod.Config()
        cfg = replace(
            cfg,
            robot=replace(cfg.robot, name=self.robot_name),
            pioneer=replace(cfg.pioneer, port=pioneer_port, baudrate=self._pioneer_baud()),
            laser=replace(cfg.laser, port=laser_port, baudrate=self._laser_baud(),
                          resolution=self.p.resolution),
            store=replace(cfg.store, state_dir=self.state_dir),
        )
        if self.listen is not None:
            cfg = replace(cfg, zenoh=replace(cfg.zenoh, listen=tuple(self.listen)))
        return cfg

    def _laser_baud(self) -> int:
        # The line's times are the device's, in wall seconds, while the world runs ``speed`` times
        # faster: a scan arrives its sweep and transmission after its first ray (the emulator samples
        # the world then, as the reader dates it), 104 ms at 38400 baud, a simulated second at 10x.
        # 500 kbaud makes it 14 ms of wall time.
        return 38400 if self.speed <= 1.0 else max(LASER_BAUDS)

    def _pioneer_baud(self) -> int:
        # The same for the SIPs: one reaches the host 32 ms (wall) after it was sampled at 9600 baud,
        # after the scan of that instant has arrived at 500 kbaud, so the service would extrapolate
        # every scan's odometry over 0.2-0.3 simulated seconds (the lab world's frames then came
        # out 0.2-0.9 m off where the stepped simulation's are 0.1 m). At 115200 a SIP takes 2.7 ms.
        return 9600 if self.speed <= 1.0 else max(PIONEER_BAUDS)

    def _new_mapper(self, cfg, doc):
        # A simulation always starts a new map: the world is new to the robot.
        self.mapper = LockedMapper(new_mapper(cfg.mapper_params()))
        return self.mapper

    def run(self) -> Summary:
        from service.pipeline import Service

        p = self.p
        stop = threading.Event()
        result: dict[str, Any] = {}
        limit = p.duration if p.duration is not None else p.max_duration
        finished = False
        odometry = Track()
        with self.devices as dev:
            cfg = self._config(dev.pioneer_path, dev.laser_path)
            service = self.service = Service(cfg, new_mapper=self._new_mapper)

            def serve() -> None:
                try:
                    result["status"] = service.run(stop)
                except BaseException as exc:  # reported by the caller
                    result["error"] = exc
                    stop.set()

            thread = threading.Thread(target=serve, name="asrmap-service", daemon=True)
            thread.start()
            try:
                finished = self._drive(service, stop, limit, odometry)
            finally:
                stop.set()
                thread.join(10.0)
        if "error" in result:
            raise result["error"]
        mapper = self.mapper.mapper if self.mapper else None
        doc = map_document(mapper, self.robot_name) if mapper is not None else {"asrs": []}
        # The mapper's clock is the host's monotonic clock: truth is on the simulated one.
        to_sim = self.devices.to_sim
        odo_sim = Track([to_sim(t) for t in odometry.t], odometry.poses)
        doc_sim = _retime(doc, to_sim)
        s = summarise(self.world, doc_sim, self.robot, odo_sim,
                      self.mapper.entered_from if self.mapper else {}, self.explorer, self.sim_clock(),
                      time.monotonic() - self.devices.wall0, finished,
                      [(to_sim(t), a, b) for t, a, b in self.mapper.crossings] if self.mapper else [])
        w = service.worker
        if w is not None:
            s.scans = w.counters.get("scans_mapped", 0)
        s.scans_dropped = getattr(service.scans, "dropped", 0)
        self.document = doc
        self.final_pose = w.last_pose if w is not None else None
        return s

    def _drive(self, service, stop: threading.Event, limit: float, odometry: Track) -> bool:
        """The explorer loop: once per newly mapped scan, read the mapper, command the robot. True
        when done. The explorer steers by the scan the mapper took last, with the pose the mapper
        gave it (as the live service's ``Exploration`` does), not by a newer scan at an older pose."""
        last_scan = None
        next_progress = 0.0
        period = self.p.scan_period / self.speed
        while not stop.is_set():
            now = self.sim_clock()
            if now >= limit or self._user_stop.is_set():
                return False
            latest = service.odometry.latest() if hasattr(service, "odometry") else None
            if latest is not None and (not odometry.t or latest[0] > odometry.t[-1]):
                odometry.append(latest[0], latest[1])
            scan = self.mapper.scan if self.mapper is not None else None
            dev = service.pioneer.device
            odo_now = getattr(dev, "odometry", None) if dev is not None else None
            sip = getattr(odo_now, "sip", None)
            stalled = bool(getattr(sip, "left_stall", False) or getattr(sip, "right_stall", False))
            if scan is None or scan is last_scan or dev is None or self.mapper is None:
                time.sleep(min(0.01, period / 4))
                continue
            last_scan = scan
            if self.explorer is not None:
                with self.mapper.lock:  # a snapshot: the mapper thread must not wait for the planning
                    view = self.mapper.view(copy=True)
                    scan = last_scan = self.mapper.scan  # the scan of the view's pose
                pts = scan_points(np.asarray(scan.ranges, float), np.asarray(scan.angles, float),
                                  float(getattr(scan, "max_range", LMS_MAX_RANGE)), self.explorer.p)
                if view.current is None:
                    cmd = Command(0.0, 0.0, "waiting for the first ASR")
                else:
                    try:
                        cmd = self.explorer.step(view, pts, now, stalled)
                    except Exception:  # an ASR changed under the snapshot: next scan, next try
                        log.debug("explorer step failed on a changing map", exc_info=True)
                        cmd = self.command
                self.command = cmd
                with contextlib.suppress(Exception):
                    _send_velocity(dev, cmd.v, cmd.w)
                if cmd.done and self.p.duration is None:
                    with contextlib.suppress(Exception):
                        dev.stop()
                    return True
            if self.progress is not None and now >= next_progress:
                next_progress = now + 1.0
                self.progress(now, self.command.status, self.mapper)
        return False


def _send_velocity(dev: Any, v: float, w: float) -> None:
    """Command ``v`` m/s and ``w`` rad/s through the Pioneer driver (VEL + RVEL)."""
    dev.set_velocity(v, w)


def _retime(doc: dict, f: Callable[[float], float]) -> dict:
    """The document with ``created`` and cycle times mapped through ``f`` (host clock -> simulated)."""
    out = dict(doc)
    out["asrs"] = [{**a, "created": f(a["created"])} for a in doc.get("asrs", [])]
    out["cycles"] = [{**c, "time": f(c["time"])} for c in doc.get("cycles", [])]
    return out


def world_frame_of(robot: SimRobot, doc: dict) -> Pose:
    """The global map frame's pose in the world frame (the first ASR's true frame), for pictures."""
    if not doc.get("asrs"):
        return robot.world.start
    first = doc["asrs"][0]
    return compose(robot.true_pose_at(first["created"]), inverse(tuple(first["origin"])))
