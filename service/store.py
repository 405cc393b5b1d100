"""The durable map store: the map document (``asrmap/map/1``) in SQLite, one row per ASR.

The service commits each change of the map as it happens, before publishing it, so that whatever a
subscriber has seen survives a crash, a SIGKILL or a watchdog restart: on start, :meth:`MapStore.load`
returns the document and the mapper continues from it (``Mapper.from_document``).

Layout: ``asrs`` (one row per ASR id, its JSON), ``links`` (one row per (from ASR, exit)),
``cycles`` (one row per cycle record, in order), ``extra`` (any other top-level key of the
document, e.g. the robot name or state the mapper keeps to continue). Journal: WAL with
``synchronous=NORMAL``: a process killed mid-write loses at most the transaction in flight, never
the file; a power cut can lose the last transactions but leaves the file consistent.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

SCHEMA = "asrmap/map/1"

_DDL = """
CREATE TABLE IF NOT EXISTS asrs (id INTEGER PRIMARY KEY, doc TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS links (src INTEGER NOT NULL, exit TEXT NOT NULL, doc TEXT NOT NULL,
                                  PRIMARY KEY (src, exit));
CREATE TABLE IF NOT EXISTS cycles (seq INTEGER PRIMARY KEY, doc TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS extra (key TEXT PRIMARY KEY, doc TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS state (key TEXT PRIMARY KEY, doc TEXT NOT NULL);
"""


def _dumps(v: Any) -> str:
    return json.dumps(v, separators=(",", ":"), allow_nan=False)


class StoreError(OSError):
    """The map store cannot be opened or written (a path, a permission, a full disk)."""


@dataclass(frozen=True)
class Synced:
    """What one :meth:`MapStore.sync` wrote: ``rows`` in all, and the ids of the ASRs upserted."""

    rows: int
    asrs: list[int]


class MapStore:
    """One SQLite file holding one robot's map. Use from one thread (the mapper's).

    A file that fails SQLite's integrity check is moved aside (``<name>.corrupt-<unix time>``) and
    a fresh map started: a robot that cannot start because of its own state file is worse than one
    that maps again.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if self.path.exists() and not self.path.is_file():
            raise StoreError(f"the map store {self.path} is a directory or a device, not a file; set "
                             "[store] path to a file name inside [store] state_dir")
        if self.path.parent.exists() and not self.path.parent.is_dir():
            raise StoreError(f"cannot open the map store {self.path}: {self.path.parent} is not a "
                             "directory; check [store] state_dir")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = self._open()
        except (OSError, sqlite3.OperationalError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise StoreError(f"cannot open the map store {self.path}: {reason}; check [store] state_dir "
                             "and its permissions (under systemd: StateDirectory=asrmap)") from None
        # What is on disk, as JSON text per row, so that sync() writes only what changed.
        self._asrs: dict[int, str] = {}
        self._links: dict[tuple[int, str], str] = {}
        self._cycles: list[str] = []
        self._extra: dict[str, str] = {}
        self._read_rows()

    def _open(self) -> sqlite3.Connection:
        try:
            db = self._connect()
            if db.execute("PRAGMA quick_check").fetchone()[0] == "ok":
                return db
            db.close()
            problem = "failed its integrity check"
        except sqlite3.DatabaseError as exc:
            problem = f"is unreadable ({exc})"
        aside = self.path.with_name(f"{self.path.name}.corrupt-{int(time.time())}")
        log.error("map store %s %s; moved to %s, starting a new map", self.path, problem, aside)
        os.replace(self.path, aside)
        for suffix in ("-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        return self._connect()

    def _connect(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        db.executescript(_DDL)
        return db

    def _read_rows(self) -> None:
        self._asrs = dict(self._db.execute("SELECT id, doc FROM asrs"))
        self._links = {(s, e): d for s, e, d in self._db.execute("SELECT src, exit, doc FROM links")}
        self._cycles = [d for (d,) in self._db.execute("SELECT doc FROM cycles ORDER BY seq")]
        self._extra = dict(self._db.execute("SELECT key, doc FROM extra"))

    def load(self) -> dict[str, Any] | None:
        """The stored map document (ASRs by id, links and cycles in order), or None if empty."""
        if not (self._asrs or self._links or self._cycles or self._extra):
            return None
        doc: dict[str, Any] = {"schema": SCHEMA}
        doc.update({k: json.loads(v) for k, v in self._extra.items()})
        doc["asrs"] = [json.loads(self._asrs[i]) for i in sorted(self._asrs)]
        doc["links"] = [json.loads(v) for _, v in sorted(self._links.items())]
        doc["cycles"] = [json.loads(v) for v in self._cycles]
        return doc

    def sync(self, doc: dict[str, Any]) -> Synced:
        """Commit what differs between ``doc`` and the store in one transaction.

        ASRs are upserted by id; links by (``from``, ``exit``); cycles by position; ASRs or links
        no longer in ``doc`` are deleted (a document is the whole map).
        """
        asrs = {int(a["id"]): _dumps(a) for a in doc.get("asrs", ())}
        links = {(int(ln["from"]), str(ln["exit"])): _dumps(ln) for ln in doc.get("links", ())}
        cycles = [_dumps(c) for c in doc.get("cycles", ())]
        extra = {k: _dumps(v) for k, v in doc.items() if k not in ("asrs", "links", "cycles", "schema")}
        up_asrs = [(i, d) for i, d in asrs.items() if self._asrs.get(i) != d]
        del_asrs = [(i,) for i in self._asrs if i not in asrs]
        up_links = [(s, e, d) for (s, e), d in links.items() if self._links.get((s, e)) != d]
        del_links = [k for k in self._links if k not in links]
        up_cycles = [(n, d) for n, d in enumerate(cycles) if n >= len(self._cycles) or self._cycles[n] != d]
        up_extra = [(k, d) for k, d in extra.items() if self._extra.get(k) != d]
        del_extra = [(k,) for k in self._extra if k not in extra]
        n = sum(map(len, (up_asrs, del_asrs, up_links, del_links, up_cycles, up_extra, del_extra)))
        n += max(0, len(self._cycles) - len(cycles))
        if not n:
            return Synced(0, [])
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
            db.executemany("INSERT OR REPLACE INTO asrs (id, doc) VALUES (?, ?)", up_asrs)
            db.executemany("DELETE FROM asrs WHERE id = ?", del_asrs)
            db.executemany("INSERT OR REPLACE INTO links (src, exit, doc) VALUES (?, ?, ?)", up_links)
            db.executemany("DELETE FROM links WHERE src = ? AND exit = ?", del_links)
            db.executemany("INSERT OR REPLACE INTO cycles (seq, doc) VALUES (?, ?)", up_cycles)
            db.execute("DELETE FROM cycles WHERE seq >= ?", (len(cycles),))
            db.executemany("INSERT OR REPLACE INTO extra (key, doc) VALUES (?, ?)", up_extra)
            db.executemany("DELETE FROM extra WHERE key = ?", del_extra)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        self._asrs, self._links, self._cycles, self._extra = asrs, links, cycles, extra
        return Synced(n, [i for i, _ in up_asrs])

    def save_pose(self, asr: int, pose: tuple[float, float, float]) -> None:
        """Remember where the robot is: ``pose`` (m, m, rad) in the frame of ASR ``asr``. Kept apart
        from the map (it changes every scan) so that a restart can resume there."""
        self._db.execute("INSERT OR REPLACE INTO state (key, doc) VALUES ('pose', ?)",
                         (_dumps({"asr": int(asr), "pose": [float(v) for v in pose]}),))

    def load_pose(self) -> tuple[int, tuple[float, float, float]] | None:
        """The last :meth:`save_pose`, or None."""
        row = self._db.execute("SELECT doc FROM state WHERE key = 'pose'").fetchone()
        if row is None:
            return None
        d = json.loads(row[0])
        return int(d["asr"]), tuple(d["pose"])

    def archive(self, why: str) -> Path:
        """Move the stored map aside (``<name>.<why>-<unix time>``) and start an empty one; returns
        where it went. For a map the mapper cannot continue: never overwrite what was mapped."""
        self._db.close()
        aside = self.path.with_name(f"{self.path.name}.{why}-{int(time.time())}")
        os.replace(self.path, aside)
        for suffix in ("-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        log.warning("map store %s moved to %s (%s)", self.path, aside, why)
        self._db = self._connect()
        self._read_rows()
        return aside

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> MapStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
