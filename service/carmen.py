"""Reader of CARMEN text logs (``.clf``/``.log``, ``.gz`` opened transparently).

A :class:`CarmenReader` is a plain iterator of frozen typed records, in file order:
:class:`LaserRecord` (``FLASER`` and ``ROBOTLASER1`` lines), :class:`OdomRecord` (``ODOM``) and
:class:`ParamRecord` (``PARAM``). ``#`` comments and message types this reader does not decode
(``NEFF``, ``SYNC``, ``RAWLASER*`` ...) are skipped and counted. A malformed line is reported as a
``logging`` warning naming the file and line number, skipped and counted; reading never raises
on content (only on a file that cannot be opened).

Times are the ``ipc_timestamp`` of each line (s). Ranges in metres, angles in radians; poses
``(x, y, theta)`` exactly as logged (in a raw log, a FLASER's ``x y theta`` is the odometry pose;
in a corrected log it is the corrected pose). Line formats: ``../shared/data/SOURCES.md``.

:func:`mapper_inputs` turns a log into the time-ordered stream of :class:`mapper.types.Odometry`
and :class:`mapper.types.Scan` readings the mapper consumes (replay, tests, benchmarks).
"""

from __future__ import annotations

import collections
import gzip
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapper.types import MIN_BEAM_SPACING, Odometry, Scan

log = logging.getLogger(__name__)

#: Readings at or beyond this range (m) are *no return* (SICK cm mode logs them as 81.91 m).
NO_RETURN_M = 50.0

Pose = tuple[float, float, float]


@dataclass(frozen=True, slots=True, eq=False)
class LaserRecord:
    """One laser sweep from a ``FLASER`` or ``ROBOTLASER1`` line.

    ``t``: ipc timestamp (s); ``ranges``: float32 (m), beam i at ``angle_min + i * angle_increment``
    (rad, laser frame, counter-clockwise); readings >= ``max_range`` (m) are no return.
    ``pose``: the robot pose as logged (FLASER ``x y theta``; ROBOTLASER1 ``robot_x y theta``);
    ``odom_pose``: FLASER ``odom_x y theta`` (None for ROBOTLASER1); ``laser_pose``: ROBOTLASER1
    ``laser_x y theta`` (None for FLASER). ``kind``: the message name; ``line``: 1-based line number.
    """

    t: float
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    max_range: float
    pose: Pose
    odom_pose: Pose | None
    laser_pose: Pose | None
    kind: str
    logger_t: float
    line: int

    def scan(self) -> Scan:
        """This sweep as a mapper :class:`~mapper.types.Scan` (laser frame, metres, radians)."""
        return Scan(self.t, self.ranges, self.angle_min, self.angle_increment, self.max_range)


@dataclass(frozen=True, slots=True)
class OdomRecord:
    """An ``ODOM`` line: pose (m, m, rad) in the odometry frame, ``tv`` (m/s), ``rv`` (rad/s), ``t`` (s)."""

    t: float
    x: float
    y: float
    theta: float
    tv: float
    rv: float
    accel: float
    line: int

    @property
    def pose(self) -> Pose:
        return (self.x, self.y, self.theta)


@dataclass(frozen=True, slots=True)
class ParamRecord:
    """A ``PARAM name value`` line; ``value`` is the text as logged."""

    name: str
    value: str
    line: int


Record = LaserRecord | OdomRecord | ParamRecord


def flaser_geometry(n: int) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` (rad) of an n-beam FLASER sweep: -90° .. +90° inclusive.

    Per SOURCES.md beam i is at -90° + i * 180°/(n-1): n = 181 gives 1°, 361 gives 0.5°; n = 180
    (the Intel log) gives 180°/179, i.e. the first and last beams still sit at ±90°.
    """
    return -math.pi / 2.0, math.pi / (n - 1)


class MalformedLine(ValueError):
    """A line whose fields do not match its message format."""


class LogFormatError(ValueError):
    """A log with nothing usable in it (no laser scan at all): the message names the file."""


def _num(text: str, what: str) -> float:
    """A finite number; NaN or infinity in a pose, a time or an angle is a malformed line."""
    x = float(text)
    if not math.isfinite(x):
        raise MalformedLine(f"{what} is {text!r}, not a finite number")
    return x


def _count(text: str, what: str) -> int:
    """A whole number of readings; anything else is a malformed line."""
    try:
        return int(text)
    except ValueError:
        raise MalformedLine(f"{what} is {text!r}, not a whole number") from None


def _ranges(fields: list[str]) -> np.ndarray:
    """Ranges (m) as float32; one too large for float32 (1e308) is infinite: no return."""
    with np.errstate(over="ignore"):
        return np.asarray(fields, dtype=np.float32)


def _pose(f: list[str], i: int, what: str = "pose") -> Pose:
    return (_num(f[i], what), _num(f[i + 1], what), _num(f[i + 2], what))


def _flaser(f: list[str], line: int) -> LaserRecord:
    n = _count(f[1], "the number of readings")
    if n < 2 or len(f) != 2 + n + 6 + 3:
        raise MalformedLine(f"FLASER with {n} readings needs {2 + n + 9} fields, found {len(f)}")
    ranges = _ranges(f[2 : 2 + n])
    k = 2 + n
    amin, inc = flaser_geometry(n)
    return LaserRecord(
        t=_num(f[k + 6], "timestamp"),
        ranges=ranges,
        angle_min=amin,
        angle_increment=inc,
        max_range=NO_RETURN_M,
        pose=_pose(f, k),
        odom_pose=_pose(f, k + 3, "odometry pose"),
        laser_pose=None,
        kind="FLASER",
        logger_t=_num(f[k + 8], "logger timestamp"),
        line=line,
    )


def _robotlaser1(f: list[str], line: int) -> LaserRecord:
    # ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode n r1..rn
    #   n_rem [rem] laser_x y theta robot_x y theta tv rv forward_safety side_safety turn_axis ipc host logger
    start, res, max_range = _num(f[2], "start_angle"), _num(f[4], "angular_res"), _num(f[5], "max_range")
    n = _count(f[8], "the number of readings")
    k = 9 + n
    n_rem = _count(f[k], "the number of remission values")
    k += 1 + n_rem
    if n < 2 or len(f) != k + 6 + 5 + 3:
        raise MalformedLine(f"ROBOTLASER1 with {n} readings needs {k + 14} fields, found {len(f)}")
    if not (abs(res) >= MIN_BEAM_SPACING and abs(res) * (n - 1) <= 2 * math.pi + 1e-6) or max_range <= 0:
        raise MalformedLine(f"ROBOTLASER1 geometry: {n} beams {res!r} rad apart, max range {max_range!r} m "
                            "is not a laser sweep")
    return LaserRecord(
        t=_num(f[k + 11], "timestamp"),
        ranges=_ranges(f[9 : 9 + n]),
        angle_min=start,
        angle_increment=res,
        max_range=min(max_range, NO_RETURN_M),
        pose=_pose(f, k + 3),
        odom_pose=None,
        laser_pose=_pose(f, k, "laser pose"),
        kind="ROBOTLASER1",
        logger_t=_num(f[k + 13], "logger timestamp"),
        line=line,
    )


def _odom(f: list[str], line: int) -> OdomRecord:
    if len(f) != 10:
        raise MalformedLine(f"ODOM needs 10 fields, found {len(f)}")
    x, y, th = _pose(f, 1)
    tv, rv, acc = (float(v) for v in f[4:7])
    t = _num(f[7], "timestamp")
    return OdomRecord(t, x, y, th, tv, rv, acc, line)


def _param(f: list[str], line: int) -> ParamRecord:
    if len(f) < 3:
        raise MalformedLine(f"PARAM needs a name and a value, found {len(f) - 1} fields")
    # PARAM name value [host logger_t]: values never contain spaces in CARMEN
    return ParamRecord(f[1], f[2], line)


def _check(rec: Record) -> None:
    """Raise ValueError where the mapper would refuse the record's readings (absurd poses, a sweep
    that is not one): such a line is malformed, skipped and counted like any other."""
    if isinstance(rec, LaserRecord):
        rec.scan()
        for pose in (rec.pose, rec.odom_pose):
            if pose is not None:
                Odometry(rec.t, *pose)
    elif isinstance(rec, OdomRecord):
        Odometry(rec.t, *rec.pose)


_PARSERS = {"FLASER": _flaser, "ROBOTLASER1": _robotlaser1, "ODOM": _odom, "PARAM": _param}


def log_lines(path: str | Path, truncated: Callable[[int], None] | None = None) -> Iterator[tuple[int, str]]:
    """(1-based line number, text) of each line of a log, plain or ``.gz`` (ASCII, bad bytes replaced).

    A ``.gz`` cut short (a copy interrupted) ends the lines where it ends: what was read stands and
    ``truncated(last line number)`` is called, if given. A ``.gz`` that is not gzip at all is a
    ``ValueError`` naming the file."""
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    no = 0
    try:
        with opener(path, "rt", encoding="ascii", errors="replace") as fh:
            for no, text in enumerate(fh, start=1):
                yield no, text
    except gzip.BadGzipFile as e:
        raise ValueError(f"{path}: not a gzip file ({e}); a plain log must not end in .gz") from e
    except EOFError:
        if truncated is not None:
            truncated(no)


class CarmenReader:
    """Iterate over the records of a CARMEN log (plain or ``.gz``), skipping what it cannot read.

    ``counters`` (a :class:`collections.Counter`) counts records by message name, plus
    ``"comment"``, ``"ignored"`` (message types not decoded here), ``"blank"`` and ``"malformed"``,
    and ``"truncated"`` once when a ``.gz`` ends early (what was read is kept, with a warning); a
    ``.gz`` that is not gzip at all is a ``ValueError`` naming the file.
    Iterating again re-reads the file and the counters start over. ``quiet`` counts malformed lines
    without a warning each (for a quick look at a log's head that a full read reports anyway).
    """

    def __init__(self, path: str | Path, quiet: bool = False):
        self.path = Path(path)
        self.quiet = quiet
        self.counters: collections.Counter[str] = collections.Counter()

    def __iter__(self) -> Iterator[Record]:
        self.counters = collections.Counter()
        for no, text in log_lines(self.path, self._truncated):
            rec = self._parse(text, no)
            if rec is not None:
                yield rec

    def _truncated(self, after: int) -> None:
        self.counters["truncated"] += 1
        log.warning("%s: the compressed file ends early, after line %d: the rest is missing",
                    self.path, after)

    def _parse(self, text: str, no: int) -> Record | None:
        f = text.split()
        if not f:
            self.counters["blank"] += 1
            return None
        if f[0].startswith("#"):
            self.counters["comment"] += 1
            return None
        parser = _PARSERS.get(f[0])
        if parser is None:
            self.counters["ignored"] += 1
            return None
        try:
            rec = parser(f, no)
            _check(rec)
        except (ValueError, IndexError) as e:
            self.counters["malformed"] += 1
            if not self.quiet:
                why = f"too few fields ({len(f) - 1} after {f[0]})" if isinstance(e, IndexError) else e
                log.warning("%s:%d: malformed %s line skipped: %s", self.path, no, f[0], why)
            return None
        self.counters[f[0]] += 1
        return rec


def read(path: str | Path) -> Iterator[Record]:
    """Shorthand for ``iter(CarmenReader(path))``."""
    return iter(CarmenReader(path))


def mapper_inputs(path: str | Path, odometry: str = "flaser") -> Iterator[Odometry | Scan]:
    """The log as the time-ordered stream the mapper consumes: Odometry and Scan readings.

    ``odometry="flaser"`` (raw logs): every laser line yields an :class:`Odometry` at its time from
    the logged robot pose (FLASER ``odom_x y theta``, which equals ``x y theta`` in a raw log;
    ROBOTLASER1 ``robot_x y theta``), then its :class:`Scan`. ``odometry="odom"``: Odometry comes
    from the ``ODOM`` lines only and the laser lines give only Scans. Records out of time order
    are passed through as they are: the mapper interpolates odometry at each scan's time.
    """
    if odometry not in ("flaser", "odom"):
        raise ValueError(f"odometry must be 'flaser' or 'odom', not {odometry!r}")
    for rec in CarmenReader(path):
        if isinstance(rec, LaserRecord):
            if odometry == "flaser":
                p = rec.odom_pose if rec.odom_pose is not None else rec.pose
                yield Odometry(rec.t, *p)
            yield rec.scan()
        elif isinstance(rec, OdomRecord) and odometry == "odom":
            yield Odometry(rec.t, rec.x, rec.y, rec.theta)
