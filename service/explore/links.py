"""The topological map as the planner walks it: link edges ``(ASR, exit id) -> ASR`` (borrowed through
the other side of a link where an ASR no longer has the exit named), a link travelled through the
narrower of its two exits, hops between ASRs and their cost (m between centres, global frame)."""

from __future__ import annotations

import math

import numpy as np

from mapper.se2 import inverse, transform_points
from mapper.types import ASR, Exit
from service.explore.crossing import SIDE, side_openings
from service.explore.params import ExploreParams
from service.explore.view import MapView


def centre_distance(a: ASR, b: ASR) -> float:
    """The cost of a hop from ``a`` to ``b`` (m): the distance between their centres in the global
    frame, plus 0.5 m."""
    ca = transform_points(a.origin, np.array([a.centre]))[0]
    cb = transform_points(b.origin, np.array([b.centre]))[0]
    # A hop costs at least a little so that routes through many tiny ASRs are not free.
    return float(np.hypot(*(ca - cb))) + 0.5


def link_edges(view: MapView, borrow: bool = False) -> dict[tuple[int, str], int]:
    """(ASR, exit id) -> destination ASR, from exit records and links (both directions unless one-way).

    ``borrow``: where the mapper recorded only one side's exit of a link (the other is None), the
    missing side crosses the known one, *borrowed* into its frame (:func:`exit_of`); and a
    duplicate ASR (the same space as its original, method.md §5.5) may leave through its
    original's exits, borrowed likewise."""
    edges: dict[tuple[int, str], int] = {}
    ids: dict[int, set[str]] = {}
    for a in view.asrs.values():
        ids[a.id] = {e.id for e in a.exits}
        for e in a.exits:
            if e.to is not None:
                edges[(a.id, e.id)] = e.to
    for ln in view.links:
        # An exit the ASR no longer has (the mapper renumbers the exits of an ASR that grows) is
        # as good as missing: the other side's is borrowed.
        here = ln.exit is not None and ln.exit in ids.get(ln.src, ())
        there = ln.via is not None and ln.via in ids.get(ln.dst, ())
        if ln.exit is not None:
            edges.setdefault((ln.src, ln.exit), ln.dst)
        if borrow and not here and there:
            edges.setdefault((ln.src, f"{BORROWED}{ln.dst}|{ln.via}"), ln.dst)
        if not ln.oneway and ln.via is not None:
            edges.setdefault((ln.dst, ln.via), ln.src)
        if not ln.oneway and borrow and not there and here:
            edges.setdefault((ln.dst, f"{BORROWED}{ln.src}|{ln.exit}"), ln.src)
    if borrow:
        _narrow_side(view, edges)
        for a in view.asrs.values():
            m = a.duplicate_of
            if m is None or m not in view.asrs:
                continue
            for (src, e), dst in list(edges.items()):
                if src == m and not e.startswith(BORROWED) and dst != a.id:
                    edges.setdefault((a.id, f"{BORROWED}{m}|{e}"), dst)
    return edges


#: m. The two exits of a link whose midpoints lie farther apart than this (global frame) are not
#: one doorway seen from both sides (see :func:`_narrow_side`).
LINK_GAP = 1.5


def _narrow_side(view: MapView, edges: dict[tuple[int, str], int]) -> None:
    """Where the two exits of a two-way link lie more than ``LINK_GAP`` apart (global frame), both
    ways go through the narrower one (the other side's borrowed, :func:`exit_of`): the wider is
    an occlusion the mapper took for the entrance, not the doorway crossed. ``lab`` seed 23: the
    west corridor entered at its corner, ASR 17's entrance an occlusion chord from the corner 7 m
    up the corridor's far wall; backtracking through it, the robot crossed it in the middle of
    the corridor into the south corridor's ASR, and never found its way back east."""
    for ln in view.links:
        if ln.oneway or ln.exit is None or ln.via is None:
            continue
        src, dst = view.asrs.get(ln.src), view.asrs.get(ln.dst)
        if src is None or dst is None:
            continue
        a, b = exit_of(view, src, ln.exit), exit_of(view, dst, ln.via)
        if a is None or b is None:
            continue
        ma = transform_points(src.origin, np.array([a.midpoint]))[0]
        mb = transform_points(dst.origin, np.array([b.midpoint]))[0]
        if float(np.hypot(*(ma - mb))) <= LINK_GAP:
            continue
        wide, narrow, wide_exit, narrow_exit = (src, dst, a, b) if a.width > b.width else (dst, src, b, a)
        if edges.get((wide.id, wide_exit.id)) == narrow.id:
            del edges[(wide.id, wide_exit.id)]
            edges[(wide.id, f"{BORROWED}{narrow.id}|{narrow_exit.id}")] = narrow.id


def within_hops(edges: dict[tuple[int, str], int], start: int, hops: int) -> set[int]:
    """The ASRs at most ``hops`` links from ``start`` (itself included), links taken both ways."""
    adjacent: dict[int, set[int]] = {}
    for (a, _), b in edges.items():
        adjacent.setdefault(a, set()).add(b)
        adjacent.setdefault(b, set()).add(a)
    seen, frontier = {start}, {start}
    for _ in range(hops):
        frontier = {b for a in frontier for b in adjacent.get(a, ())} - seen
        seen |= frontier
    return seen


BORROWED = "<"  # prefix of a borrowed exit id: "<" + source ASR + "|" + its exit id


def exit_of(view: MapView, asr: ASR, exit_id: str, p: ExploreParams | None = None) -> Exit | None:
    """Exit ``exit_id`` of ``asr``; a borrowed id (see :func:`link_edges`) gives the other ASR's exit
    carried into this ASR's frame through the global frame both are placed in; a side opening's id
    (:func:`side_openings`, with ``p``) the piece of its exit's run nearest the midpoint it names."""
    if SIDE in exit_id:  # a side opening: the piece of its exit's run nearest where it was (0.5 m)
        base_id, _, where = exit_id.partition(SIDE)
        base = exit_of(view, asr, base_id)
        x, _, y = where.partition(",")
        if base is None:
            return None
        at = np.array([float(x), float(y)]) / 100.0
        near = [(float(np.hypot(*(np.asarray(e.midpoint) - at))), e)
                for e in side_openings(asr, base, p or ExploreParams())]
        d, e = min(near, key=lambda q: q[0], default=(math.inf, None))
        return None if e is None or d > 0.5 else Exit(exit_id, e.a, e.b)
    if not exit_id.startswith(BORROWED):
        return next((e for e in asr.exits if e.id == exit_id), None)
    src_id, _, src_exit = exit_id[len(BORROWED):].partition("|")
    src = view.asrs.get(int(src_id))
    ex = next((e for e in src.exits if e.id == src_exit), None) if src is not None else None
    if ex is None:
        return None
    ends = transform_points(inverse(asr.origin), transform_points(src.origin, np.array([ex.a, ex.b])))
    a, b = ends.tolist()
    return Exit(exit_id, (a[0], a[1]), (b[0], b[1]), src.id)
