"""The service's Zenoh side: the key table of shared/design/interfaces.md under ``asrmap/<robot>/``.

Publishers (declared once): ``event``, ``pose``, ``status``, ``scan``; ``asr/<id>`` is a put on
the session with the computed key. Queryables: ``map`` (the whole map document; ``?since=N``
keeps the ASRs with id >= N), ``cmd/stop`` and ``cmd/explore`` (error reply and no effect unless
listed in ``[zenoh] allow_commands``). Liveliness token: ``alive``.

Every JSON payload carries ``"schema": "asrmap/<kind>/1"`` and is sent with the encoding
``application/json;asrmap/<kind>/1``; scans are binary (:func:`encode_scan`) with the encoding
``application/octet-stream;asrmap/scan/1``.

Zenoh calls callbacks on its own threads and one slow callback delays every subscription of the
session, so callbacks here only ``put_nowait`` the query into a queue; one worker thread answers.
The session must be closed (``close()`` in a ``finally``) or the interpreter never exits; and no
``fork`` may follow ``open()``.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import struct
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from service.config import COMMANDS, ZenohConfig

log = logging.getLogger(__name__)

PREFIX = "asrmap"


class BusError(ConnectionError):
    """The Zenoh session could not be opened as configured (a busy port, a bad zenoh file)."""


def json_encoding(kind: str) -> zenoh.Encoding:
    """``application/json;asrmap/<kind>/1``."""
    return zenoh.Encoding("application/json").with_schema(f"{PREFIX}/{kind}/1")


SCAN_ENCODING = zenoh.Encoding("application/octet-stream").with_schema(f"{PREFIX}/scan/1")
_SCAN_HEAD = struct.Struct("<dfffI")


def encode_scan(t: float, ranges: np.ndarray, angle_min: float, angle_increment: float,
                max_range: float) -> bytes:
    """``asrmap/scan/1``: little-endian float64 ``t`` (s), float32 ``angle_min``, ``angle_increment``
    (rad, laser frame), ``max_range`` (m), uint32 beam count n, then n float32 ranges (m)."""
    r = np.ascontiguousarray(ranges, dtype="<f4")
    return _SCAN_HEAD.pack(t, angle_min, angle_increment, max_range, len(r)) + r.tobytes()


def decode_scan(data: bytes) -> dict[str, Any]:
    """Inverse of :func:`encode_scan`; raises ValueError on a short or inconsistent payload."""
    if len(data) < _SCAN_HEAD.size:
        raise ValueError(f"scan payload of {len(data)} bytes is shorter than its header ({_SCAN_HEAD.size})")
    t, a0, da, rmax, n = _SCAN_HEAD.unpack_from(data)
    if len(data) != _SCAN_HEAD.size + 4 * n:
        raise ValueError(f"scan payload says {n} beams but holds {(len(data) - _SCAN_HEAD.size) / 4:g}")
    ranges = np.frombuffer(data, dtype="<f4", offset=_SCAN_HEAD.size).astype(float)
    return {"t": t, "angle_min": a0, "angle_increment": da, "max_range": rmax, "ranges": ranges}


def dumps(kind: str, body: dict[str, Any]) -> bytes:
    """JSON bytes of ``body`` with ``"schema": "asrmap/<kind>/1"`` first."""
    return json.dumps({"schema": f"{PREFIX}/{kind}/1", **{k: v for k, v in body.items() if k != "schema"}},
                      separators=(",", ":")).encode()


# Without scouting there is nothing to wait for at open (zenoh waits scouting/delay, 500 ms, by default).
_NO_SCOUTING = {"delay": 0, "multicast": {"enabled": False}, "gossip": {"enabled": False}}


def peer_config(z: ZenohConfig) -> zenoh.Config:
    """The service's session: ``z.config`` if given, else a peer on ``z.listen`` without scouting.

    Scouting is off because a robot's service should say where it can be reached rather than
    multicast itself onto whatever network it is plugged into.
    """
    if z.config:
        try:
            return zenoh.Config.from_file(z.config)
        except zenoh.ZError as exc:
            raise BusError(f"zenoh.config {z.config}: {_reason(exc)}") from None
    return _from_json5({
        "mode": "peer",
        "listen": {"endpoints": list(z.listen)},
        "connect": {"endpoints": list(z.connect)},
        "scouting": _NO_SCOUTING,
    }, "zenoh.listen / zenoh.connect")


def client_config(connect: list[str] | tuple[str, ...]) -> zenoh.Config:
    """A session for tools (monitor, tests) that reaches a service or router at ``connect``.

    A peer that listens nowhere rather than a zenoh client: a client's ``open`` fails when the
    robot is not up yet, a peer keeps retrying and connects when it appears.
    """
    return _from_json5({
        "mode": "peer",
        "listen": {"endpoints": []},
        # Retry every 0.1-1 s (default 1-4 s) so a tool sees a robot soon after it comes up.
        "connect": {"endpoints": list(connect),
                    "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}},
        "scouting": _NO_SCOUTING,
    }, "--connect")


_RUST_SOURCE = re.compile(r"\s+at \S+\.rs:\d+\.?")


def _reason(exc: zenoh.ZError) -> str:
    """zenoh's message without the Rust source location it appends at every layer."""
    return _RUST_SOURCE.sub("", str(exc)).strip()


def _from_json5(cfg: dict[str, Any], what: str) -> zenoh.Config:
    """A zenoh configuration; a bad endpoint is a :class:`BusError` naming ``what`` set it."""
    try:
        return zenoh.Config.from_json5(json.dumps(cfg))
    except zenoh.ZError as exc:
        raise BusError(f"{what}: {_reason(exc)} (an endpoint looks like tcp/127.0.0.1:7447)") from None


def open_session(cfg: zenoh.Config, what: str) -> zenoh.Session:
    """``zenoh.open`` with its errors as :class:`BusError` naming ``what`` was being opened."""
    try:
        return zenoh.open(cfg)
    except zenoh.ZError as exc:
        reason = _reason(exc)
        if "in use" in reason:
            reason += ("; is another asrmap running? choose another port ([zenoh] listen in the config, "
                       "--listen for asrmap simulate)")
        raise BusError(f"cannot open the zenoh session ({what}): {reason}") from None


def robot_key(robot: str, *chunks: str) -> str:
    return "/".join((PREFIX, robot, *chunks))


class CommandRefused(Exception):
    """A command query that is not obeyed; its message goes back in the error reply."""


class Bus:
    """The Zenoh session of one robot's service.

    ``document()`` returns the current map document (called on the worker thread per map query);
    ``on_command(name, params)`` runs an allowed command and returns a JSON-able result, or raises
    :class:`CommandRefused`/``ValueError``. Use as a context manager or call :meth:`close`.
    """

    def __init__(self, robot: str, zcfg: ZenohConfig, document: Callable[[], dict | None],
                 on_command: Callable[[str, dict[str, str]], dict] | None = None):
        self.robot = robot
        self.zcfg = zcfg
        self._document = document
        self._on_command = on_command
        self._queries: queue.Queue = queue.Queue(maxsize=64)
        self._stop = threading.Event()
        self.session: zenoh.Session | None = None
        self._decls: list = []
        self.counters = {"queries": 0, "queries_dropped": 0, "commands_refused": 0, "published": 0}
        what = f"config {zcfg.config}" if zcfg.config else f"listen {', '.join(zcfg.listen) or 'nothing'}"
        self.session = open_session(peer_config(zcfg), what)
        try:
            self._declare()
        except BaseException:
            self.close()
            raise
        self._worker = threading.Thread(target=self._serve, name="zenoh-queries", daemon=True)
        self._worker.start()

    def key(self, *chunks: str) -> str:
        return robot_key(self.robot, *chunks)

    def _declare(self) -> None:
        s = self.session
        self._pubs = {k: s.declare_publisher(self.key(k), encoding=json_encoding(k))
                      for k in ("event", "pose", "status")}
        self._pubs["scan"] = s.declare_publisher(self.key("scan"), encoding=SCAN_ENCODING)
        self._decls = list(self._pubs.values())
        for name in ("map", *(f"cmd/{c}" for c in COMMANDS)):
            self._decls.append(s.declare_queryable(self.key(name), self._enqueue(name)))
        self._decls.append(s.liveliness().declare_token(self.key("alive")))

    def _enqueue(self, name: str):
        def callback(q: zenoh.Query) -> None:
            try:
                self._queries.put_nowait((name, q))
            except queue.Full:
                # Dropping the query finalizes it: the asker gets no reply rather than a late one.
                self.counters["queries_dropped"] += 1

        return callback

    # --- publishing (any thread) -------------------------------------------------------------------

    def publish_event(self, event: dict[str, Any]) -> None:
        self._put("event", dumps("event", event))

    def publish_pose(self, pose: dict[str, Any]) -> None:
        self._put("pose", dumps("pose", pose))

    def publish_status(self, status: dict[str, Any]) -> None:
        self._put("status", dumps("status", status))

    def publish_scan(self, t: float, ranges, angle_min: float, angle_increment: float,
                     max_range: float) -> None:
        self._put("scan", encode_scan(t, ranges, angle_min, angle_increment, max_range))

    def publish_asr(self, asr: dict[str, Any]) -> None:
        s = self.session
        if s is not None:
            try:
                s.put(self.key("asr", str(int(asr["id"]))), dumps("asr", asr), encoding=json_encoding("asr"))
                self.counters["published"] += 1
            except zenoh.ZError as exc:  # closing under our feet: the store already has it
                log.debug("asr %s not published: %s", asr["id"], exc)

    def _put(self, kind: str, payload: bytes) -> None:
        if self.session is not None:
            try:
                self._pubs[kind].put(payload)
                self.counters["published"] += 1
            except zenoh.ZError as exc:
                log.debug("%s not published: %s", kind, exc)

    # --- queries (worker thread) ------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                name, q = self._queries.get(timeout=0.2)
            except queue.Empty:
                continue
            self.counters["queries"] += 1
            try:
                if name == "map":
                    self._answer_map(q)
                else:
                    self._answer_command(name.split("/", 1)[1], q)
            except Exception as exc:  # a bad query must never end the worker
                log.exception("answering %s failed", name)
                self._reply_err(q, f"internal error: {exc}")
            finally:
                q.drop()

    def _reply_err(self, q: zenoh.Query, message: str) -> None:
        try:
            q.reply_err(dumps("error", {"error": message}), encoding=json_encoding("error"))
        except zenoh.ZError:
            pass

    def _params(self, q: zenoh.Query, allowed: tuple[str, ...]) -> dict[str, str]:
        params = {k: v for k, v in dict(q.parameters).items() if not k.startswith("_")}
        unknown = sorted(set(params) - set(allowed))
        if unknown:
            raise ValueError(f"unknown parameter {', '.join(unknown)}; expected "
                             + (", ".join(allowed) if allowed else "none"))
        return params

    def _answer_map(self, q: zenoh.Query) -> None:
        try:
            params = self._params(q, ("since",))
            since = None
            if "since" in params:
                try:
                    since = int(params["since"])
                except ValueError:
                    since = -1
                if since < 0:
                    raise ValueError(f"since: expected an ASR id (integer >= 0); found {params['since']!r}")
        except ValueError as exc:
            self._reply_err(q, str(exc))
            return
        doc = self._document() or {"robot": self.robot, "asrs": [], "links": [], "cycles": []}
        if since is not None:
            doc = {**doc, "asrs": [a for a in doc.get("asrs", ()) if int(a["id"]) >= since]}
        q.reply(self.key("map"), dumps("map", doc), encoding=json_encoding("map"))

    def _answer_command(self, name: str, q: zenoh.Query) -> None:
        if name not in self.zcfg.allow_commands or self._on_command is None:
            self.counters["commands_refused"] += 1
            log.warning("refused command %s (not in [zenoh] allow_commands)", name)
            self._reply_err(q, f"command {name} is disabled: add \"{name}\" to [zenoh] allow_commands")
            return
        try:
            params = {k: v for k, v in dict(q.parameters).items() if not k.startswith("_")}
            result = self._on_command(name, params)
        except (CommandRefused, ValueError) as exc:
            self.counters["commands_refused"] += 1
            self._reply_err(q, str(exc))
            return
        log.info("command %s obeyed", name)
        q.reply(self.key("cmd", name), dumps("command", {"command": name, **(result or {})}),
                encoding=json_encoding("command"))

    # --- lifecycle --------------------------------------------------------------------------------

    def close(self) -> None:
        """Undeclare everything and close the session (bounded by zenoh's own close timeout)."""
        self._stop.set()
        s, self.session = self.session, None
        if s is None:
            return
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except zenoh.ZError:
                pass
        self._decls = []
        s.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
