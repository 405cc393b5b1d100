"""Constructed ASR records for the topology and cycle tests: boxes placed in a true world.

Each ASR is an axis-aligned box in *true* world coordinates seen from a true frame pose; its record
holds the box in its own frame (as the mapper would build it). The global map composes its origin
from *drifted* crossing poses, so the tests control the drift exactly.
"""

from __future__ import annotations

import math

import numpy as np

from mapper.globalmap import GlobalMap
from mapper.se2 import Pose, between, compose, transform_points
from mapper.types import ASR, Exit

SIDES = ("S", "E", "N", "W")  # box edges in counter-clockwise order, starting at (x0, y0)


def box_asr(asr_id: int, box, frame: Pose, exits: str = "", t: float | None = None) -> ASR:
    """ASR ``asr_id``: box (x0, y0, x1, y1) in world metres, its frame at world pose ``frame``;
    the box sides named in ``exits`` (``S``, ``E``, ``N``, ``W``) are exits, the others surfaces."""
    x0, y0, x1, y1 = box
    world = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    inv = between(frame, (0.0, 0.0, 0.0))
    local = transform_points(inv, world)
    edges = ["exit" if s in exits else "surface" for s in SIDES]
    ex = [
        Exit(f"{asr_id}/{n}", tuple(local[k]), tuple(local[(k + 1) % 4]))
        for n, k in enumerate(k for k, s in enumerate(SIDES) if s in exits)
    ]
    centre = transform_points(inv, np.array([[(x0 + x1) / 2, (y0 + y1) / 2]]))[0]
    return ASR(
        id=asr_id,
        created=float(asr_id if t is None else t),
        origin=(0.0, 0.0, 0.0),
        boundary=local,
        edges=edges,
        centre=(float(centre[0]), float(centre[1])),
        exits=ex,
        scans=10,
    )


def drift(k: int, per_step: Pose) -> Pose:
    """Accumulated odometry error after k transitions: a global rigid motion (m, m, rad)."""
    return (per_step[0] * k, per_step[1] * k, per_step[2] * k)


def nearest_exit(asr: ASR, frame: Pose, world_point) -> str | None:
    """The id of the exit of ``asr`` (frame at world pose ``frame``) nearest a world point."""
    if not asr.exits:
        return None
    mids = transform_points(frame, np.array([e.midpoint for e in asr.exits]))
    return asr.exits[int(np.argmin(np.hypot(*(mids - np.asarray(world_point)).T)))].id


def drive(gm: GlobalMap, route, per_step: Pose = (0.0, 0.0, 0.0)):
    """Feed ASRs to ``gm`` in order as a robot driving through them would; returns all events.

    ``route``: list of (box, true frame pose, exit sides). Each ASR after the first is created by
    crossing the previous ASR's exit nearest the new frame; the crossing pose carries the drift.
    """
    events = []
    believed = []
    truth = []
    for n, (box, frame, exits) in enumerate(route, start=1):
        asr = box_asr(n, box, frame, exits)
        d = compose(drift(n - 1, per_step), frame) if n > 1 else frame
        if n == 1:
            asr.origin = frame
            gm.add_first(asr)
        else:
            prev = gm.asrs[n - 1]
            crossed = nearest_exit(prev, truth[-1], frame[:2])
            via = nearest_exit(asr, frame, frame[:2])
            crossing = between(believed[-1], d)
            events += gm.add_created(asr, n - 1, crossed, via, crossing, float(n))
        believed.append(d)
        truth.append(frame)
    return events


def heading(a, b) -> float:
    return math.atan2(b[1] - a[1], b[0] - a[0])
