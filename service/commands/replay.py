"""``asrmap replay``: a CARMEN log through the mapper; map document, picture, figures against truth."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from mapper.cycle_params import CycleParams
from service.argtypes import distinct_files, output_file, speed, write_output

NAME = "replay"
HELP = "feed a CARMEN log (.gz ok) to the mapper; print ASRs, cycles, precision, recall, scans/s"
EXAMPLE = (
    "asrmap replay intel-raw-first5505.clf.gz --truth intel-corrected.log.gz --json map.json --svg map.svg"
)


def add_arguments(p) -> None:
    p.add_argument("log", help="CARMEN log (FLASER/ROBOTLASER1/ODOM lines; .gz read transparently)")
    p.add_argument("--json", metavar="OUT", type=output_file,
                   help="write the map document (asrmap/map/1) here")
    p.add_argument("--svg", metavar="OUT", type=output_file,
                   help="write the picture (topological beside global metric map) here")
    p.add_argument("--truth", metavar="LOG", help="a corrected log of the same run: its poses are the truth")
    p.add_argument(
        "--logged-poses",
        action="store_true",
        help="use a corrected log's corrected poses as odometry (default: rebuild the drifting raw odometry)",
    )
    p.add_argument(
        "--paper",
        action="store_true",
        help="the paper's plain cycle check only (no hindsight/verification/realign)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--through-serial", action="store_true",
                   help="play the log through the emulated Pioneer and LMS200 on ptys and the whole service")
    p.add_argument("--speed", default=1.0, type=speed, metavar="N|max",
                   help="with --through-serial: N times faster than recorded, or 'max' (the line's limit)")
    p.add_argument("--ignore-baud", action="store_true",
                   help="with --through-serial: send scans when due even where the baud would not allow it")


class Bar:
    """A plain-text progress bar on stderr, redrawn at most five times a second."""

    def __init__(self, stream=None):
        self.stream, self.last = stream, 0.0

    def __call__(self, done: int, total: int, spent: float) -> None:
        now = time.monotonic()
        if now - self.last < 0.2 and done < total:
            return
        self.last = now
        frac = done / total if total else 1.0
        rate = done / spent if spent > 0 else 0.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        out = self.stream or sys.stderr
        out.write(f"\r[{bar}] {100 * frac:5.1f}% {done}/{total} scans, {rate:,.0f} scans/s ")
        if done >= total:
            out.write("\n")
        out.flush()


def _fmt(x: float, pct: bool = False) -> str:
    if isinstance(x, float) and math.isnan(x):
        return "n/a"
    return f"{100 * x:.1f}%" if pct else f"{x:.3f}"


def _drift_line(drift) -> str:
    if not drift:
        return "revisit drift: no revisits"
    d = np.asarray(drift)
    return (f"revisit drift (dead-reckoned ASR frames against truth): median {np.median(d):.2f} m, "
            f"90% {np.percentile(d, 90):.2f} m, within 2 m {np.mean(d <= 2.0):.0%}")


def _transition_line(errors) -> str:
    if not errors:
        return "transition error: no transitions"
    e = np.asarray(errors)
    heading = np.degrees(np.abs(e[:, 2]))
    per_m = np.abs(e[:, 2]) / np.maximum(e[:, 0], 0.2)
    return (f"transition error (dead-reckoned frame in its parent's, {len(e)} transitions, median "
            f"{np.median(e[:, 0]):.1f} m apart): position median {np.median(e[:, 1]):.2f} m, 90% "
            f"{np.percentile(e[:, 1], 90):.2f} m; heading median {np.median(heading):.1f} deg, 90% "
            f"{np.percentile(heading, 90):.1f} deg, RMS {np.sqrt(np.mean(per_m**2)):.3f} rad/m")


def summary(res) -> list[str]:
    """The figures of a replay, one per line."""
    from service.evaluate import describe_false
    doc = res.document
    accepted = sum(1 for c in doc["cycles"] if c["accepted"])
    lines = [
        f"log: {res.scans} scans over {res.log_seconds:.1f} s ({res.mode})",
        f"ASRs: {len(doc['asrs'])}, links: {len(doc['links'])}, cycles: {accepted} accepted, "
        f"{len(doc['cycles']) - accepted} rejected",
        f"throughput: {res.scans_per_second:,.0f} scans/s, {res.realtime_factor:,.0f}x real time "
        f"({res.mapper_seconds:.2f} s in the mapper)",
    ]
    ev = res.evaluation
    if ev is not None:
        lines += [
            f"precision: {_fmt(ev.precision, True)} ({ev.true_positives} of {ev.cycles} cycles truly overlap)"
            + (f", false: {describe_false(ev.false_depths)}" if ev.false_depths else ""),
            f"revisits: {ev.revisits}, detected: {ev.detected}, recall: {_fmt(ev.recall, True)} "
            f"({ev.evaluated} of {ev.asrs} ASRs inside the truth's time span)",
            _drift_line(ev.revisit_drift),
            _transition_line(ev.transition_errors),
            f"ASR frame error (rigid fit, RMS): before realignment {ev.frame_error_before:.2f} m / "
            f"{ev.heading_error_before:.3f} rad, after {ev.frame_error_after:.2f} m / "
            f"{ev.heading_error_after:.3f} rad",
        ]
    return lines


def run(args) -> int:
    from service.replay import params_for_log, replay  # the mapper is imported only when replaying

    distinct_files({"LOG": args.log, "--truth": args.truth}, {"--json": args.json, "--svg": args.svg})
    params = params_for_log(args.log)
    if args.paper and hasattr(params, "cycles"):
        params = dataclasses.replace(params, cycles=CycleParams.paper())
    if args.through_serial:
        from service.serial_replay import serial_replay

        res = serial_replay(args.log, params=params, truth=args.truth, logged_poses=args.logged_poses,
                            speed=args.speed, rate_limit=not args.ignore_baud,
                            progress=None if args.no_progress else Bar())
    else:
        res = replay(args.log, params=params, truth=args.truth, logged_poses=args.logged_poses,
                     progress=None if args.no_progress else Bar())
    for line in summary(res):
        print(line)
    if args.through_serial:
        c = res.counters
        print(f"serial: {res.speed:.1f}x, {res.wall_seconds:.1f} s, scans sent {c['scans_sent']}, skipped by "
              f"the line {c['scans_skipped']}, dropped by the pipeline {c['scans_dropped']}, mapped "
              f"{c['scans_mapped']}; motors {'stopped' if res.motors_stopped else 'NOT STOPPED'}")
    if args.json:
        write_output(args.json, json.dumps(res.document))
    if args.svg:
        from service.render import write_svg

        write_svg(args.svg, res.document, title=f"asrmap replay {Path(args.log).name}")
    return 0
