"""The live service: the Pioneer and the laser through their drivers, the mapper on its own thread,
the map store, Zenoh, systemd.

Threads and what each may wait on:

- the drivers' reader threads: serial only. Their callbacks append odometry to an
  :class:`~service.buffers.OdometryBuffer` and scans to a :class:`~service.buffers.DropOldest`
  queue, and return: serial reading never waits for the mapper; when the mapper falls behind, the
  oldest waiting scan is dropped and counted.
- one :class:`~service.device_link.Link` thread per device: opens the driver (handshakes can take
  seconds), watches for silence, reports ``fault``/``recovered`` and reopens the device without
  restarting the service.
- the mapper thread (:class:`~service.mapper_worker.MapperWorker`): pose at each scan's time,
  ``Mapper.add_odometry`` + ``add_scan``, store commit, then publication (commit first: what was
  published survives a crash).
- the main thread (:meth:`Service.run`): READY/WATCHDOG/STOPPING, status, safety. It pings the
  systemd watchdog only while the mapper thread is not stuck, so a wedged mapper gets restarted.

Clocks: every timestamp is ``time.monotonic()`` seconds of this host (drivers stamp readings with it).
Frames: odometry in the odometry frame (continuous across Pioneer reconnections, see
:class:`~service.buffers.OdometryBuffer`), poses in ASR frames and the global frame as the mapper
defines them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from service.buffers import DropOldest, OdometryBuffer
from service.bus import Bus, CommandRefused
from service.config import Config
from service.device_link import Link
from service.mapper_worker import Exploration, MapperWorker, make_mapper
from service.motion import MotionGate, stop_on_thread_crash
from service.notify import Notifier
from service.store import MapStore

log = logging.getLogger(__name__)


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
            if stored and stored.get("asrs") and not mapper.document().get("asrs"):
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
