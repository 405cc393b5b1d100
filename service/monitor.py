"""Watching robots over Zenoh: which are alive, their maps, live status and events.

A :class:`Monitor` discovers robots by their liveliness tokens (``asrmap/<robot>/alive``), fetches
each map from its ``map`` queryable when the robot appears, keeps it current from the ``asr/<id>``
puts (and refetches it after events that change links or cycles), and turns everything into
:class:`Update` items that the CLI prints. Zenoh callbacks only enqueue; :meth:`Monitor.poll`
runs on the caller's thread.
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from service.bus import PREFIX, client_config, open_session
from service.render import render_svg, robot_pose

log = logging.getLogger(__name__)

# Events after which the links or cycles of the map may have changed: the map is fetched again.
_REFETCH = {"exit_crossed", "cycle_detected", "cycle_rejected", "map_realigned"}


@dataclass
class Update:
    """One thing that happened: ``kind`` is alive, gone, map, event, status, asr or pose."""

    kind: str
    robot: str
    data: dict[str, Any] = field(default_factory=dict)
    #: With a status: the robot's latest pose (``asrmap/pose/1``), None before the first.
    pose: dict[str, Any] | None = None


@dataclass
class RobotView:
    """What is known of one robot: its map document, latest status and pose, liveliness."""

    name: str
    alive: bool = False
    doc: dict[str, Any] | None = None
    status: dict[str, Any] | None = None
    pose: dict[str, Any] | None = None
    changed: bool = False


class Monitor:
    """Subscribes to ``asrmap/<robot>/...`` (``robot`` ``*`` for all) through ``connect``."""

    def __init__(self, connect: list[str], robot: str = "*", *, session: zenoh.Session | None = None):
        self.robot = robot
        self._own = session is None
        self.session = session or open_session(client_config(connect), f"connect {', '.join(connect)}")
        self.robots: dict[str, RobotView] = {}
        self._q: queue.Queue = queue.Queue(maxsize=10000)
        self.dropped = 0
        self.bad_payloads = 0
        self._warned: set[tuple[str, str]] = set()
        try:
            base = f"{PREFIX}/{robot}"
            self._decls = [
                self.session.declare_subscriber(f"{base}/event", self._on_sample("event")),
                self.session.declare_subscriber(f"{base}/status", self._on_sample("status")),
                self.session.declare_subscriber(f"{base}/pose", self._on_sample("pose")),
                self.session.declare_subscriber(f"{base}/asr/*", self._on_sample("asr")),
                # Last, so that a robot seen alive is already subscribed to (declarations are in order).
                self.session.liveliness().declare_subscriber(f"{base}/alive", self._on_alive, history=True),
            ]
        except BaseException:
            self.close()
            raise

    # --- callbacks (zenoh threads): copy out and enqueue only --------------------------------------

    def _put(self, item: tuple) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _on_alive(self, s: zenoh.Sample) -> None:
        self._put(("alive" if s.kind == zenoh.SampleKind.PUT else "gone", str(s.key_expr), b""))

    def _on_sample(self, kind: str):
        def cb(s: zenoh.Sample) -> None:
            self._put((kind, str(s.key_expr), s.payload.to_bytes()))

        return cb

    # --- the caller's thread -----------------------------------------------------------------------

    def fetch_map(self, robot: str, timeout: float = 2.0) -> dict[str, Any] | None:
        """The robot's map document from its queryable, or None when it does not answer (or answers
        with something that is not an ``asrmap/map/1`` document: warned about and counted)."""
        for r in self.session.get(f"{PREFIX}/{robot}/map", timeout=timeout):
            if r.ok:
                doc = self._decode(robot, "map", r.ok.payload.to_bytes())
                if doc is not None and isinstance(doc.get("asrs"), list):
                    return doc
                if doc is not None:
                    self._bad(robot, "map", "a map document without a list of ASRs")
                return None
            log.warning("map query to %s failed: %s", robot, r.err.payload.to_string())
        return None

    def _bad(self, robot: str, kind: str, what: str) -> None:
        """A payload that is not what the key promises (another program, another version): skipped,
        counted, and warned about once per robot and kind."""
        self.bad_payloads += 1
        if (robot, kind) not in self._warned:
            self._warned.add((robot, kind))
            log.warning("%s sent a %s that is %s: skipped (further ones are counted in silence)", robot,
                        kind, what)

    def _decode(self, robot: str, kind: str, payload: bytes) -> dict[str, Any] | None:
        """The JSON object of an ``asrmap/<kind>/1`` payload, or None (see :meth:`_bad`)."""
        try:
            data = json.loads(payload)
        except (ValueError, RecursionError):  # RecursionError: arrays nested thousands deep
            self._bad(robot, kind, "not JSON")
            return None
        if not isinstance(data, dict) or data.get("schema") != f"{PREFIX}/{kind}/1":
            self._bad(robot, kind, f"not an {PREFIX}/{kind}/1 object")
            return None
        return data

    def poll(self, timeout: float = 0.2) -> list[Update]:
        """Updates that arrived within ``timeout`` seconds (at least one waited for, then all queued)."""
        out: list[Update] = []
        try:
            item = self._q.get(timeout=timeout)
        except queue.Empty:
            return out
        while True:
            out.extend(self._handle(*item))
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                return out

    def _view(self, robot: str) -> RobotView:
        if robot not in self.robots:
            self.robots[robot] = RobotView(robot)
        return self.robots[robot]

    def _handle(self, kind: str, key: str, payload: bytes) -> list[Update]:
        robot = key.split("/")[1]
        view = self._view(robot)
        if kind == "gone":
            view.alive = False
            return [Update("gone", robot)]
        if kind == "alive":
            view.alive = True
            return [Update("alive", robot), *self._refresh(view)]
        data = self._decode(robot, kind, payload)
        if data is None:
            return []
        if kind == "status":
            view.status = data
        elif kind == "pose":
            view.pose = data
            view.changed = True
            return []  # ~10 Hz: drawn in the pictures and shown with the next status line
        elif kind == "asr":
            if not isinstance(data.get("id"), int):
                self._bad(robot, kind, "an ASR without an integer id")
                return []
            if view.doc is not None:
                data.pop("schema", None)
                asrs = [a for a in view.doc["asrs"] if a["id"] != data["id"]]
                view.doc["asrs"] = sorted([*asrs, data], key=lambda a: a["id"])
                view.changed = True
            return []  # printed as the events asr_created/asr_updated describe them
        out = [Update(kind, robot, data, pose=view.pose if kind == "status" else None)]
        if kind == "event" and data.get("event") in _REFETCH:
            out += self._refresh(view)
        return out

    def _refresh(self, view: RobotView) -> list[Update]:
        doc = self.fetch_map(view.name)
        if doc is None:
            return []
        view.doc, view.changed = doc, True
        return [Update("map", view.name, doc)]

    def close(self) -> None:
        for d in getattr(self, "_decls", []):
            try:
                d.undeclare()
            except zenoh.ZError:
                pass
        self._decls = []
        if self._own:
            self.session.close()

    def __enter__(self) -> Monitor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- one line per update ------------------------------------------------------------------------------


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, list | tuple):
        return "(" + ", ".join(_fmt(i) for i in v) + ")"
    return str(v)


def map_summary(doc: dict[str, Any]) -> str:
    cycles = doc.get("cycles", [])
    accepted = sum(1 for c in cycles if c.get("accepted"))
    return (f"{len(doc.get('asrs', []))} ASRs, {len(doc.get('links', []))} links, "
            f"{len(cycles)} cycles ({accepted} accepted)")


def _table(v: Any) -> dict[str, Any]:
    """``v`` if it is a JSON object, else an empty one (a status from another version)."""
    return v if isinstance(v, dict) else {}


def _where(pose: dict[str, Any] | None) -> str | None:
    """``at ASR 7 (5.12, 3.20 m, 45°)``: the robot's ASR and global pose (m, degrees, global frame)
    from an ``asrmap/pose/1`` body; None when there is none or it is malformed."""
    asr, g = robot_pose(pose)
    if g is None:
        return None
    return f"at ASR {asr} ({g[0]:.2f}, {g[1]:.2f} m, {math.degrees(g[2]):.0f}°)"


def status_line(st: dict[str, Any], pose: dict[str, Any] | None = None) -> str:
    """One line of a status (``asrmap/status/1``), with the robot's latest ``pose`` when given."""
    parts = []
    for dev in ("pioneer", "laser"):
        d = _table(st.get(dev))
        faults = f"({d['faults']} faults)" if d.get("faults") else ""
        parts.append(f"{dev}={d.get('link', '?')}{faults}")
    rates = _table(st.get("rates"))
    parts += [f"{k}={_fmt(v)}/s" for k, v in rates.items()]
    timing = _table(st.get("timing"))
    if timing.get("latency") is not None:
        parts.append(f"latency={timing['latency'] * 1000:.0f} ms")
    if timing.get("realtime_factor") is not None:
        parts.append(f"rtf={_fmt(timing['realtime_factor'])}")
    if timing.get("cpu_share") is not None:
        parts.append(f"cpu={timing['cpu_share'] * 100:.0f}%")
    if timing.get("skew") is not None:
        parts.append(f"skew={timing['skew'] * 1000:.0f} ms")
    if st.get("battery") is not None:
        parts.append(f"battery={_fmt(st['battery'])} V")
    motors = _table(st.get("motors"))
    if motors.get("e_stop"):
        parts.append("E-STOP")
    elif motors.get("enabled") is False:
        parts.append("motors=off")
    parts.append(f"dropped_scans={st.get('dropped_scans', 0)}")
    if "asrs" in st:
        parts.append(f"asrs={st['asrs']}")
    if st.get("waiting_for"):
        parts.append(f"waiting for {st['waiting_for']}")
    explore = _table(st.get("explore"))
    if explore.get("status") and explore["status"] != "idle":
        parts.append(f"explore: {explore['status']}")
    stop = _table(st.get("last_stop"))
    if stop.get("reason"):
        # Both times are the service's monotonic clock (s): the age needs no clock of ours.
        now, then = st.get("t"), stop.get("t")
        ago = (f" {max(0.0, now - then):.0f} s ago" if isinstance(now, int | float)
               and isinstance(then, int | float) else "")
        parts.append(f"last stop{ago}: {stop['reason']}")
    where = _where(pose)
    if where:
        parts.append(where)
    parts += [f"ALERT {a}" for a in motors.get("alerts") or ()]
    return " ".join(parts)


def format_update(u: Update) -> str:
    """The terminal line for one update."""
    if u.kind in ("alive", "gone"):
        return f"{u.robot}  {u.kind}"
    if u.kind == "map":
        return f"{u.robot}  map: {map_summary(u.data)}"
    if u.kind == "status":
        try:
            return f"{u.robot}  status {status_line(u.data, u.pose)}"
        except (TypeError, ValueError, KeyError) as exc:  # a field of another type (another version)
            return f"{u.robot}  status (unreadable: {type(exc).__name__}: {exc})"
    fields = " ".join(f"{k}={_fmt(v)}" for k, v in u.data.items() if k not in ("schema", "event"))
    return f"{u.robot}  {u.data.get('event', u.kind)} {fields}"


class SvgWriter:
    """Keeps a picture of each robot's map current, rewritten at most every ``period`` seconds.

    A ``{robot}`` in ``path`` is replaced by the robot name (one file per robot); without it the
    file shows the robot whose map changed last. Written to a temporary file and renamed, so a
    viewer reloading the file never reads half a picture.
    """

    def __init__(self, path: str, period: float = 1.0):
        self.path = path
        self.period = period
        self._due = 0.0

    def target(self, robot: str) -> Path:
        return Path(self.path.replace("{robot}", robot))

    def update(self, mon: Monitor, now: float | None = None) -> list[Path]:
        """Write the pictures of the robots whose map changed; returns the files written."""
        now = time.monotonic() if now is None else now
        if now < self._due:
            return []
        self._due = now + self.period
        written = []
        for view in mon.robots.values():
            if not view.changed or view.doc is None:
                continue
            view.changed = False
            out = self.target(view.name)
            tmp = out.with_name(f".{out.name}.tmp")
            title = f"{view.name}: {map_summary(view.doc)}"
            try:
                svg = render_svg(view.doc, title, robot=view.pose)
            except Exception as exc:  # a malformed ASR from the robot must not end the watching
                log.warning("cannot draw %s's map (%s: %s); the picture is not updated", view.name,
                            type(exc).__name__, exc)
                continue
            tmp.write_text(svg, encoding="utf-8")
            os.replace(tmp, out)
            written.append(out)
        return written


def discover(mon: Monitor, wait: float, stop: threading.Event | None = None) -> list[Update]:
    """Updates gathered for ``wait`` seconds (the robots alive now and their maps), or until
    ``stop`` is set (Ctrl-C, SIGTERM)."""
    out: list[Update] = []
    deadline = time.monotonic() + wait
    while (left := deadline - time.monotonic()) > 0 and not (stop is not None and stop.is_set()):
        out += mon.poll(min(left, 0.1))
    return out
