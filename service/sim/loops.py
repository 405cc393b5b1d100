"""The world's loops, from ground truth: which ones the robot drove round and which ones its map closed.

The world's **holes** are the obstacles with free space all the way round them (a table island
with its chairs, a stretch of wall between two doorways), found by inflating everything solid by
the robot's radius (:func:`world_holes`). A closed path is counted by its **winding vector**: how
many times it turns round each hole. Going once round the corridor of ``lab`` turns round every
hole inside it; going round a table island turns round that one alone.

- The **loops driven**: the number of independent winding vectors among the loops the robot's true
  path closed by coming back near where it had been (:func:`returns`), i.e. the rank of the cycle
  space of the ground it covered, counted in holes.
- The **loops closed**: how many of those the map closed (the dimension of the intersection of
  the two spaces, :func:`loops_closed`). The map closes a loop when it knows the robot is back in a
  space it left (:func:`closures`: a re-entry through a known transition, truly into that ASR, or a
  true cycle closure of the new ASR with the earlier one), the loop being the true path between
  the robot's last crossing out of the space and its crossing back in, joined up through the space;
  and it holds a loop without
  any cycle when one ASR, or two joined by one transition, surround the hole (:func:`enclosed`: a
  table island in a room).

"Every cycle closed" (the goal of exploring ``lab``) is then every loop driven also closed: a
closure through every loop the robot drove, so that, with the map's transitions, each of its
cycles is a sum of closed ones. It does not ask that every revisit be recognised (the revisits
missed count that). :func:`count` gives the three figures of a run (the simulation summary's).
Everything here is in the world frame (the truth's): metres and radians.
"""

from __future__ import annotations

import bisect
import math

import numpy as np
import shapely
from shapely.ops import polylabel

from service.evaluate import Track, places, true_outlines
from service.explore import plan_path
from service.sim.physics import P2DX_RADIUS
from service.sim.world import World


def world_holes(world: World, clearance: float = P2DX_RADIUS) -> list[shapely.Polygon]:
    """The holes (world frame) of the free space the robot's centre can reach from the world's start:
    the obstacles inflated by ``clearance`` (m), in a stable order (by x, then y, of a point inside)."""
    x0, y0, x1, y1 = world.bounds
    free = shapely.box(x0 - 1.0, y0 - 1.0, x1 + 1.0, y1 + 1.0).difference(
        world.obstacles.buffer(clearance, quad_segs=4))
    start = shapely.Point(world.start[0], world.start[1])
    reach = [g for g in getattr(free, "geoms", [free]) if g.covers(start)]
    if not reach:
        return []
    holes = [shapely.Polygon(r) for r in reach[0].interiors]
    return sorted(holes, key=_centre)


def _centre(hole: shapely.Polygon) -> tuple[float, float]:
    """The point deepest inside the hole (m): the path passes no nearer to it than the hole's
    inscribed radius (at least the clearance, for a hole round a thin wall)."""
    c = polylabel(hole, tolerance=0.01)
    return float(c.x), float(c.y)


def _turns(xy: np.ndarray, centre: tuple[float, float]) -> np.ndarray:
    """rad: the path's unwrapped bearing from ``centre`` at each point."""
    return np.unwrap(np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0]))


def winding(xy: np.ndarray, centre: tuple[float, float]) -> int:
    """How many times the closed path ``xy`` (N, 2), last point joined to the first, turns
    counter-clockwise round ``centre`` (negative: clockwise)."""
    if len(xy) < 3:
        return 0
    a = _turns(np.vstack([xy, xy[:1]]), centre)
    return round((a[-1] - a[0]) / (2.0 * math.pi))


def _resample(xy: np.ndarray, step: float) -> np.ndarray:
    """The path's points at least ``step`` (m) apart (first and last kept)."""
    if len(xy) < 2:
        return xy
    keep = [0]
    last = xy[0]
    for i in range(1, len(xy)):
        if math.hypot(xy[i, 0] - last[0], xy[i, 1] - last[1]) >= step:
            keep.append(i)
            last = xy[i]
    if keep[-1] != len(xy) - 1:
        keep.append(len(xy) - 1)
    return xy[keep]


def _none(holes: list[shapely.Polygon]) -> np.ndarray:
    """No winding vectors: (0, len(holes))."""
    return np.zeros((0, len(holes)), dtype=np.int64)


def _distinct(w: np.ndarray) -> np.ndarray:
    """The distinct winding vectors of ``w`` (K, holes) that turn round something."""
    w = w[np.any(w != 0, axis=1)]
    return np.unique(w, axis=0) if len(w) else w


def _independent(vectors: np.ndarray) -> int:
    """How many of the winding vectors (K, holes) are linearly independent."""
    return int(np.linalg.matrix_rank(vectors.astype(float))) if vectors.size else 0


def returns(xy: np.ndarray, holes: list[shapely.Polygon], reach: float = 0.25) -> np.ndarray:
    """The winding vectors (K, len(holes)) of the loops the path ``xy`` (N, 2; world frame, m)
    closed by coming back near where it had been: for each point and each of the cells of side
    ``reach`` round it (so at most 2.83 ``reach`` away, 0.71 m), the turns round each hole of the
    path from the first point in that cell to this one, closed by the short step back. Every loop
    of the path's neighbourhood is a sum of these.

    A turn is counted from the hole's deepest point. The robot keeps its radius from every
    obstacle, so a step that short cannot pass a hole and sweeps less than 0.62π round it: the
    path's change of bearing, divided by 2π and rounded, is the loop's winding number."""
    xy = _resample(np.asarray(xy, dtype=float), 0.05)
    if len(xy) < 3 or not holes:
        return _none(holes)
    turns = np.column_stack([_turns(xy, _centre(h)) for h in holes])
    cells = np.floor(xy / reach).astype(np.int64)
    first: dict[tuple[int, int], int] = {}
    for n, (i, j) in enumerate(map(tuple, cells)):
        first.setdefault((i, j), n)
    pairs = [(first[(i + di, j + dj)], n)
             for n, (i, j) in enumerate(map(tuple, cells))
             for di in (-1, 0, 1) for dj in (-1, 0, 1)
             if first.get((i + di, j + dj), n) < n]
    if not pairs:
        return _none(holes)
    a, b = np.array(pairs).T
    return _distinct(np.rint((turns[b] - turns[a]) / (2.0 * math.pi)).astype(np.int64))


def closures(doc: dict, pairs: tuple[tuple[int, int, float], ...], crossings: list[tuple[float, int, int]],
             truth: Track, outline: dict[int, shapely.Geometry], holes: list[shapely.Polygon],
             slack: float = 0.5) -> np.ndarray:
    """The winding vectors (K, len(holes)) of the loops the map closed: each time it knew the robot
    was back in a space it had left, the true path from its last crossing out of that space to its
    crossing back in, closed across the space (:func:`_across`: through its ASRs' true outlines,
    so that the loop goes round whatever the space goes round). It knew so
    - when it re-entered a known ASR through a known transition, and the robot truly was inside
      that ASR's true outline (within ``slack``, m) on crossing in: a wrong re-entry closes nothing;
    - when a true cycle closure matched the new ASR the robot crossed into with an earlier one.
    A space is an ASR with those the map holds for the same place (duplicates).

    ``pairs``: (new ASR, earlier ASR, time) of each true closure
    (:attr:`service.evaluate.Evaluation.true_pairs`); ``crossings``: ``(t, from ASR, to ASR)`` of
    every exit crossing, on the truth's clock (:attr:`service.sim.simulator.LockedMapper.crossings`);
    ``truth``: the robot's true poses (world frame); ``outline``: each ASR's true outline
    (:func:`service.evaluate.true_outlines`)."""
    if len(truth) < 3 or not holes or not crossings:
        return _none(holes)
    same_place = places(doc)
    filled = _filled(outline)
    xy = np.array([p[:2] for p in truth.poses], dtype=float)
    back: list[tuple[float, int]] = []  # (crossing in, the space's ASR)
    first_in: dict[int, float] = {}
    for t, _, dst in crossings:
        if dst in first_in and dst in outline:
            p = truth.at(t)
            if shapely.distance(outline[dst], shapely.Point(p[0], p[1])) <= slack:
                back.append((t, dst))
        first_in.setdefault(dst, t)
    back += [(first_in[new], earlier) for new, earlier, _ in pairs if new in first_in]
    out: list[list[int]] = []
    centres = [_centre(h) for h in holes]
    for t_in, place in back:
        here = same_place(place)
        left = [t for t, src, _ in crossings if src in here and t < t_in]
        if not left:
            continue
        path = xy[bisect.bisect_left(truth.t, left[-1]): bisect.bisect_right(truth.t, t_in)]
        if len(path) >= 2:
            space = shapely.union_all([filled[k] for k in here if k in filled])
            path = np.vstack([path, _across(space, path[-1], path[0])])
        out.append([winding(path, c) for c in centres])
    return _distinct(np.array(out, dtype=np.int64).reshape(-1, len(holes)))


def _filled(outline: dict[int, shapely.Geometry]) -> dict[int, shapely.Geometry]:
    """Each ASR's true outline without its holes (world frame)."""
    return {k: shapely.union_all([shapely.Polygon(p.exterior) for p in getattr(g, "geoms", [g])
                                  if isinstance(p, shapely.Polygon) and not p.is_empty])
            for k, g in outline.items()}


def _across(space: shapely.Geometry, a: np.ndarray, b: np.ndarray, cell: float = 0.125) -> np.ndarray:
    """The points (K, 2; world frame, m) of a way from ``a`` to ``b`` through ``space`` (the true
    outlines of the ASRs of one place): none when the straight step stays inside it (within
    ``cell``), else the explorer's shortest way over a grid of ``cell`` m
    (:func:`service.explore.plan_path`, each end within 4 cells of the space); none either when
    there is no such way.

    A loop the map closed is the robot's true path out of a space and back in, joined up inside
    that space: its crossing out and its crossing back in can lie on two sides of a table the space
    goes round (the room on three sides of a table island, the fourth side another ASR), and the
    straight step between them would cut the table, losing the turn round it."""
    if space.is_empty or space.buffer(cell).covers(shapely.LineString([a, b])):
        return np.zeros((0, 2))
    way = plan_path(space, (float(a[0]), float(a[1])), (float(b[0]), float(b[1])), cell, 0.0)
    return np.zeros((0, 2)) if way is None else way


def enclosed(outline: dict[int, shapely.Geometry], crossings: list[tuple[float, int, int]],
             holes: list[shapely.Polygon], clearance: float = P2DX_RADIUS) -> np.ndarray:
    """The unit winding vectors (K, len(holes)) of the holes the map surrounds without a cycle: a
    table island whose solid part (the hole less ``clearance``, m) lies inside one ASR's true
    outline (``outline``, as for :func:`closures`), or inside two ASRs joined by one transition
    (``crossings``), the room round a table split in two. A loop round it needs no cycle of ASRs:
    one ASR's metric map, or two joined rigidly, already hold it."""
    if not outline or not holes:
        return _none(holes)
    filled = _filled(outline)
    spaces = list(filled.values())
    joined = {tuple(sorted((a, b))) for _, a, b in crossings if a != b and a in filled and b in filled}
    spaces += [shapely.union(filled[a], filled[b]) for a, b in joined]
    solid = [hole.buffer(-0.9 * clearance) for hole in holes]
    inside = [h for h, core in enumerate(solid) if not core.is_empty and any(g.covers(core) for g in spaces)]
    return np.eye(len(holes), dtype=np.int64)[inside]


def loops_closed(driven: np.ndarray, closed: np.ndarray) -> tuple[int, int]:
    """(independent loops driven, how many of them the closures closed): the dimension of the space
    the path's loops span, and of its intersection with the space the closures' loops span."""
    d, c = _independent(driven), _independent(closed)
    both = _independent(np.vstack([driven, closed])) if len(driven) and len(closed) else d + c
    return d, d + c - both


def count(world: World, doc: dict, truth: Track, odometry: Track, crossings: list[tuple[float, int, int]],
          pairs: tuple[tuple[int, int, float], ...]) -> tuple[int, int, int]:
    """(the world's holes, loops driven, loops closed) of one run: its map document ``doc``, the
    robot's ``truth`` (world frame), the ``odometry`` the mapper was given, its exit ``crossings``
    and its true closures' ``pairs`` (as for :func:`closures`), all on the truth's clock."""
    holes = world_holes(world)
    driven = returns(np.array([p[:2] for p in truth.poses], dtype=float).reshape(-1, 2), holes)
    asrs = doc.get("asrs", [])
    if not len(driven) or not asrs or not len(odometry):
        return len(holes), _independent(driven), 0
    _, outline, _ = true_outlines(asrs, truth, odometry)
    closed = np.vstack([enclosed(outline, crossings, holes),
                        closures(doc, pairs, crossings, truth, outline, holes)])
    return (len(holes), *loops_closed(driven, closed))
