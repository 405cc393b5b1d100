"""Replay a CARMEN log through the mapper, optionally scored against ground truth (library core of
``asrmap replay``; the command is a thin shell over :func:`replay`).

Inputs: a raw log gives its logged odometry; a corrected log (``*-corrected.log.gz``) is turned back
into drifting odometry from its embedded increments and its corrected poses become the truth, unless
``logged_poses`` asks for the corrected poses as odometry. ``truth`` names another log whose logged
poses are the truth of the same run (Intel raw + ``intel-corrected.log.gz``, MIT CSAIL raw +
``csail-robotlaser1.log.gz``: same timestamps). Timing covers only the mapper's calls.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from mapper.mapper import Mapper
from mapper.params import MapperParams
from mapper.types import Odometry, Scan
from service.carmen import CarmenReader, LogFormatError, ParamRecord, log_lines, mapper_inputs
from service.evaluate import (
    Evaluation,
    Track,
    evaluate,
    is_corrected,
    read_truth,
    rebuild_corrected,
    truth_from_log,
)

log = logging.getLogger(__name__)

Progress = Callable[[int, int, float], None]
"""Called as progress(scans done, scans in the log, mapper seconds so far)."""


@dataclass
class ReplayResult:
    """What a replay produced: the mapper (its map), its document, counts, timing and evaluation."""

    mapper: Mapper
    document: dict
    scans: int
    log_seconds: float
    mapper_seconds: float
    events: collections.Counter = field(default_factory=collections.Counter)
    odometry: Track = field(default_factory=Track)
    evaluation: Evaluation | None = None
    mode: str = "raw"

    @property
    def scans_per_second(self) -> float:
        return self.scans / self.mapper_seconds if self.mapper_seconds > 0 else float("inf")

    @property
    def realtime_factor(self) -> float:
        """Log duration over mapper time: how many times faster than the robot recorded it."""
        return self.log_seconds / self.mapper_seconds if self.mapper_seconds > 0 else float("inf")


def count_scans(path: str | Path) -> int:
    """Laser lines in a log (a fast text pass, for the progress bar). A ``.gz`` cut short counts
    what it holds, silently: the replay's own read warns about it."""
    return sum(1 for _, line in log_lines(path) if line.startswith(("FLASER", "ROBOTLASER1")))


MAX_LASER_OFFSET_M = 2.0  # a laser more than 2 m from the robot centre is a corrupt PARAM line


def params_for_log(path: str | Path, params: MapperParams | None = None) -> MapperParams:
    """Mapper parameters for a recorded log: the laser offset from ``PARAM robot_frontlaser_offset``,
    else 0 (the Intel, ACES and CSAIL logs' ranges are relative to the robot centre)."""
    params = params or MapperParams()
    offset = 0.0
    for n, rec in enumerate(CarmenReader(path, quiet=True)):
        if isinstance(rec, ParamRecord) and rec.name == "robot_frontlaser_offset":
            try:
                offset = float(rec.value)
            except ValueError:
                offset = math.nan
            if not abs(offset) <= MAX_LASER_OFFSET_M:  # NaN too
                log.warning("%s:%d: PARAM robot_frontlaser_offset %r is not an offset of at most %g m; "
                            "using 0", path, rec.line, rec.value, MAX_LASER_OFFSET_M)
                offset = 0.0
            break
        if n > 200:
            break
    return dataclasses.replace(params, laser_x=offset, laser_y=0.0)


def replay(
    path: str | Path,
    params: MapperParams | None = None,
    truth: str | Path | Track | None = None,
    logged_poses: bool = False,
    progress: Progress | None = None,
    inputs: Iterable[Odometry | Scan] | None = None,
) -> ReplayResult:
    """Feed a CARMEN log (``.gz`` ok) to a new :class:`~mapper.mapper.Mapper`; see the module docstring.

    ``params``: mapper parameters (default :func:`params_for_log`); ``inputs`` replaces the log's
    readings (e.g. the same log passed through the emulators and drivers).
    """
    path = Path(path)
    params = params or params_for_log(path)
    mode = "raw"
    truth_track: Track | None = truth if isinstance(truth, Track) else None
    if inputs is None:
        if not logged_poses and is_corrected(path):
            inputs, own_truth = rebuild_corrected(path)
            mode = "corrected, rebuilt odometry"
            truth_track = truth_track or own_truth
        else:
            inputs = mapper_inputs(path, "flaser")
            if logged_poses:
                mode = "logged poses"
                truth_track = truth_track or (truth_from_log(path) if is_corrected(path) else None)
    if truth is not None and not isinstance(truth, Track):
        truth_track = read_truth(truth)
    total = count_scans(path) if progress else 0
    mapper = Mapper(params, defer_views=True)  # pipelined: the same map, see mapper.mapper
    odometry = Track()
    events: collections.Counter = collections.Counter()
    scans = 0
    spent = 0.0
    t_first = t_last = None
    clock = time.perf_counter
    for reading in inputs:
        if isinstance(reading, Odometry):
            odometry.append(reading.t, reading.pose)
            tic = clock()
            out = mapper.add_odometry(reading)
        else:
            scans += 1
            t_first = reading.t if t_first is None else min(t_first, reading.t)
            t_last = reading.t if t_last is None else max(t_last, reading.t)
            tic = clock()
            out = mapper.add_scan(reading)
        spent += clock() - tic
        for e in out:
            events[e.kind] += 1
        if progress and scans % 50 == 0 and isinstance(reading, Scan):
            progress(scans, total, spent)
    tic = clock()
    out = mapper.flush()  # the last viewpoint's view (see "Pipelining" in mapper.mapper)
    spent += clock() - tic
    for e in out:
        events[e.kind] += 1
    if progress:
        progress(scans, max(total, scans), spent)
    if scans == 0:
        raise LogFormatError(f"{path}: no laser scan could be read (FLASER or ROBOTLASER1 lines); "
                             "the warnings above name the lines that were skipped")
    doc = mapper.document()
    result = ReplayResult(
        mapper=mapper,
        document=doc,
        scans=scans,
        log_seconds=(t_last - t_first) if scans else 0.0,
        mapper_seconds=spent,
        events=events,
        odometry=odometry,
        mode=mode,
    )
    if truth_track is not None and len(truth_track) and len(odometry):
        gm = mapper.globalmap
        entered = {k: gm.topology.entered_from(k) for k in gm.asrs}
        result.evaluation = evaluate(doc, truth_track, odometry, entered, gm.odometry_origin)
    return result
