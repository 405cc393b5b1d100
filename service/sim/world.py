"""A 2D world for the simulator: walls with doorways, furniture as polygons, legs as circles.

World file format (JSON, ``"schema": "asrmap/world/1"``). Units: metres and radians, in one
world frame (x right, y up, angles counter-clockwise). Every key but ``schema`` and ``start`` is
optional; unknown keys are errors (a typo must not silently drop a wall)::

    {
      "schema": "asrmap/world/1",
      "name": "lab",
      "description": "free text",
      "start": [x, y, theta],                       # the robot's true pose at power-on
      "walls": [                                     # straight walls, optionally with doorways
        {"from": [x, y], "to": [x, y],
         "doors": [{"at": 2.5, "width": 0.9}]}       # door centre 2.5 m from "from", 0.9 m gap
      ],
      "polylines": [[[x, y], [x, y], ...]],          # open chains of wall segments
      "loops": [[[x, y], [x, y], ...]],              # closed chains (last point joins the first)
      "segments": [[x1, y1, x2, y2]],                # loose segments (a bench edge, a plank)
      "polygons": [[[x, y], [x, y], [x, y], ...]],   # solid obstacles: tables, cabinets (>= 3 points)
      "circles": [[x, y, r]],                        # solid discs: chair and table legs, pillars
      "regions": {"room 1": [[x, y], ...]}           # named areas for ground truth (rooms, corridor)
    }

A doorway is a gap cut out of a wall, so the laser sees through it and the robot can pass it. The
laser sees every segment from both sides. :func:`load_world` takes a built-in name (``lab``,
``office``, ``aliasing``: ``service/sim/worlds/*.json``) or a path, and raises :class:`WorldError`
naming the file and the offending entry (``walls[3].doors[0]: ...``).
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from mapper.se2 import Pose

SCHEMA = "asrmap/world/1"
_KEYS = {"schema", "name", "description", "start", "walls", "polylines", "loops", "segments",
         "polygons", "circles", "regions"}
# Doorways narrower than this cannot be meant for a robot of the Pioneer's class (0.425 m wide):
# a likely unit or typing mistake, not a design choice.
MIN_DOOR_WIDTH = 0.3


class WorldError(ValueError):
    """A world file that cannot be used: the message names the file and the entry."""


@dataclass(frozen=True, eq=False)
class World:
    """Geometry in the world frame (metres).

    ``segments``: (N, 4) float array ``x1, y1, x2, y2`` of every line the laser can hit: walls with
    their doorways cut out, polylines, loops and the edges of ``polygons``. ``circles``: (M, 3)
    ``x, y, r``. ``polygons``: solid obstacles as (K, 2) vertex arrays. ``doors``: (D, 4) the
    doorway gaps (for ground truth and pictures). ``regions``: named ground-truth areas.
    ``start``: the robot's true pose at power-on (m, m, rad).
    """

    name: str
    start: Pose
    segments: np.ndarray
    circles: np.ndarray
    polygons: list[np.ndarray] = field(default_factory=list)
    doors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    regions: dict[str, np.ndarray] = field(default_factory=dict)
    description: str = ""
    source: str = ""

    @cached_property
    def obstacles(self) -> shapely.Geometry:
        """Everything solid as one prepared shapely geometry (for collision checks)."""
        parts = list(shapely.linestrings(self.segments.reshape(-1, 2, 2))) if len(self.segments) else []
        parts += [shapely.Polygon(p) for p in self.polygons]
        parts += [shapely.Point(x, y).buffer(r, quad_segs=8) for x, y, r in self.circles]
        geom = shapely.GeometryCollection(parts) if parts else shapely.GeometryCollection()
        shapely.prepare(geom)
        return geom

    @cached_property
    def region_polygons(self) -> dict[str, shapely.Polygon]:
        return {name: shapely.Polygon(pts) for name, pts in self.regions.items()}

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all geometry (m)."""
        pts = [self.segments.reshape(-1, 2)]
        if len(self.circles):
            c = self.circles
            pts.append(np.vstack([c[:, :2] - c[:, 2:3], c[:, :2] + c[:, 2:3]]))
        allp = np.vstack(pts) if pts else np.zeros((1, 2))
        return (float(allp[:, 0].min()), float(allp[:, 1].min()),
                float(allp[:, 0].max()), float(allp[:, 1].max()))

    def region_of(self, x: float, y: float) -> str | None:
        """Name of the first region containing the point (x, y) (m), or None."""
        p = shapely.Point(x, y)
        for name, poly in self.region_polygons.items():
            if poly.covers(p):
                return name
        return None

    def clearance(self, x: float, y: float) -> float:
        """Distance (m) from the point to the nearest obstacle (0 inside a solid one)."""
        return float(shapely.distance(shapely.Point(x, y), self.obstacles))


def builtin_worlds() -> list[str]:
    """Names of the worlds shipped in ``service/sim/worlds``."""
    root = resources.files("service.sim") / "worlds"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".json"))


def load_world(name_or_path: str | Path) -> World:
    """A built-in world by name (``lab``, ``office``, ``aliasing``) or a world file by path."""
    text = str(name_or_path)
    path = Path(text)
    if not path.suffix and not path.exists():
        if text not in builtin_worlds():
            raise WorldError(f"no world {text!r}: built-in worlds are {', '.join(builtin_worlds())}, "
                             "or give the path of a .json world file")
        res = resources.files("service.sim") / "worlds" / f"{text}.json"
        return parse_world(res.read_text(encoding="utf-8"), source=f"{text}.json")
    try:
        data = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise WorldError(f"{path}: cannot read the world file ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise WorldError(f"{path}: not a world file: not UTF-8 text (byte {exc.start})") from exc
    return parse_world(data, source=str(path))


def parse_world(text: str | dict[str, Any], source: str = "<world>") -> World:
    """Build a :class:`World` from JSON text or an already decoded dict; ``source`` names it in errors."""
    if isinstance(text, dict):
        doc = text
    else:
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            where = f"line {exc.lineno} column {exc.colno}"
            raise WorldError(f"{source}: not JSON: {exc.msg} at {where}") from exc
        except RecursionError as exc:
            raise WorldError(f"{source}: not a world: arrays or objects nested too deeply") from exc
    return _Parser(source).world(doc)


class _Parser:
    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, what: str) -> WorldError:
        return WorldError(f"{self.source}: {where}: {what}" if where else f"{self.source}: {what}")

    def number(self, v: Any, where: str, positive: bool = False) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(where, f"expected a finite number, got {v!r}")
        if positive and v <= 0:
            raise self.fail(where, f"expected a positive number, got {v!r}")
        return float(v)

    def seq(self, v: Any, where: str, n: int | None = None, min_n: int = 0) -> list:
        if not isinstance(v, list):
            raise self.fail(where, f"expected a list, got {type(v).__name__}")
        if n is not None and len(v) != n:
            raise self.fail(where, f"expected {n} numbers, got {len(v)}")
        if len(v) < min_n:
            raise self.fail(where, f"expected at least {min_n} entries, got {len(v)}")
        return v

    def point(self, v: Any, where: str) -> tuple[float, float]:
        x, y = self.seq(v, where, 2)
        return self.number(x, f"{where}[0]"), self.number(y, f"{where}[1]")

    def points(self, v: Any, where: str, min_n: int) -> np.ndarray:
        items = self.seq(v, where, min_n=min_n)
        pts = np.array([self.point(p, f"{where}[{i}]") for i, p in enumerate(items)])
        steps = np.hypot(*np.diff(pts, axis=0).T)
        if len(steps) and steps.min() == 0.0:
            i = int(np.argmin(steps))
            raise self.fail(f"{where}[{i + 1}]", "repeats the previous point")
        return pts

    def world(self, doc: Any) -> World:
        if not isinstance(doc, dict):
            raise self.fail("", "expected a JSON object at the top level")
        unknown = sorted(set(doc) - _KEYS)
        if unknown:
            raise self.fail(unknown[0], f"unknown key (known: {', '.join(sorted(_KEYS))})")
        if doc.get("schema") != SCHEMA:
            raise self.fail("schema", f"expected {SCHEMA!r}, got {doc.get('schema')!r}")
        if "start" not in doc:
            raise self.fail("start", "missing: the robot's start pose [x, y, theta] (m, m, rad)")
        start = tuple(self.number(v, f"start[{i}]") for i, v in enumerate(self.seq(doc["start"], "start", 3)))
        segs: list[np.ndarray] = []
        doors: list[list[float]] = []
        for i, w in enumerate(self.seq(doc.get("walls", []), "walls")):
            s, d = self.wall(w, f"walls[{i}]")
            segs.append(s)
            doors += d
        for i, pl in enumerate(self.seq(doc.get("polylines", []), "polylines")):
            segs.append(_chain(self.points(pl, f"polylines[{i}]", 2), closed=False))
        for i, lp in enumerate(self.seq(doc.get("loops", []), "loops")):
            segs.append(_chain(self.points(lp, f"loops[{i}]", 3), closed=True))
        for i, s in enumerate(self.seq(doc.get("segments", []), "segments")):
            where = f"segments[{i}]"
            v = [self.number(c, f"{where}[{j}]") for j, c in enumerate(self.seq(s, where, 4))]
            if v[0] == v[2] and v[1] == v[3]:
                raise self.fail(where, "zero length")
            segs.append(np.array([v]))
        polygons = []
        for i, pg in enumerate(self.seq(doc.get("polygons", []), "polygons")):
            where = f"polygons[{i}]"
            pts = self.points(pg, where, 3)
            poly = shapely.Polygon(pts)
            if not poly.is_valid or poly.area <= 0.0:
                raise self.fail(where, f"not a simple polygon ({shapely.is_valid_reason(poly)})")
            polygons.append(pts)
            segs.append(_chain(pts, closed=True))
        circles = []
        for i, c in enumerate(self.seq(doc.get("circles", []), "circles")):
            where = f"circles[{i}]"
            x, y, r = self.seq(c, where, 3)
            circles.append([self.number(x, f"{where}[0]"), self.number(y, f"{where}[1]"),
                            self.number(r, f"{where}[2]", positive=True)])
        regions = {}
        raw_regions = doc.get("regions", {})
        if not isinstance(raw_regions, dict):
            raise self.fail("regions", "expected an object of name: [[x, y], ...]")
        for name, pts in raw_regions.items():
            where = f"regions[{name!r}]"
            regions[str(name)] = self.points(pts, where, 3)
            if not shapely.Polygon(regions[str(name)]).is_valid:
                raise self.fail(where, "not a simple polygon")
        for key in ("name", "description"):
            if key in doc and not isinstance(doc[key], str):
                raise self.fail(key, f"expected a string, got {doc[key]!r}")
        world = World(
            name=doc.get("name", Path(self.source).stem),
            start=start,  # type: ignore[arg-type]
            segments=np.vstack(segs) if segs else np.zeros((0, 4)),
            circles=np.array(circles, dtype=float).reshape(-1, 3),
            polygons=polygons,
            doors=np.array(doors, dtype=float).reshape(-1, 4),
            regions=regions,
            description=doc.get("description", ""),
            source=self.source,
        )
        if not world.segments.size and not world.circles.size:
            raise self.fail("", "the world has no walls, segments, polygons or circles")
        gap = world.clearance(start[0], start[1])
        if gap < 0.3:
            raise self.fail("start", f"the robot's centre ({start[0]:g}, {start[1]:g}) is {gap:.2f} m "
                            "from an obstacle; a Pioneer 2DX needs at least 0.3 m")
        return world

    def wall(self, w: Any, where: str) -> tuple[np.ndarray, list[list[float]]]:
        if not isinstance(w, dict):
            raise self.fail(where, 'expected {"from": [x, y], "to": [x, y], "doors": [...]}')
        extra = sorted(set(w) - {"from", "to", "doors"})
        if extra:
            raise self.fail(f"{where}.{extra[0]}", "unknown key (known: from, to, doors)")
        for k in ("from", "to"):
            if k not in w:
                raise self.fail(where, f"missing {k!r}")
        a = np.array(self.point(w["from"], f"{where}.from"))
        b = np.array(self.point(w["to"], f"{where}.to"))
        length = float(np.hypot(*(b - a)))
        if length == 0.0:
            raise self.fail(where, "zero length")
        gaps = []
        for j, d in enumerate(self.seq(w.get("doors", []), f"{where}.doors")):
            dw = f"{where}.doors[{j}]"
            if not isinstance(d, dict) or set(d) != {"at", "width"}:
                raise self.fail(dw, 'expected {"at": metres from the wall\'s "from", "width": metres}')
            at = self.number(d["at"], f"{dw}.at")
            width = self.number(d["width"], f"{dw}.width", positive=True)
            if width < MIN_DOOR_WIDTH:
                raise self.fail(dw, f"width {width:g} m is narrower than {MIN_DOOR_WIDTH} m "
                                "(units are metres)")
            lo, hi = at - width / 2.0, at + width / 2.0
            if lo < 0.0 or hi > length:
                raise self.fail(dw, f"door from {lo:.3f} to {hi:.3f} m does not fit the wall "
                                f"(length {length:.3f} m)")
            gaps.append((lo, hi, dw))
        gaps.sort()
        for (_, hi0, w0), (lo1, _, w1) in itertools.pairwise(gaps):
            if lo1 < hi0:
                raise self.fail(w1, f"overlaps {w0}")
        u = (b - a) / length
        cuts = [0.0] + [c for lo, hi, _ in gaps for c in (lo, hi)] + [length]
        pieces = [(s, e) for s, e in zip(cuts[0::2], cuts[1::2], strict=True) if e - s > 1e-9]
        segs = np.array([[*(a + s * u), *(a + e * u)] for s, e in pieces]).reshape(-1, 4)
        doors = [[*(a + lo * u), *(a + hi * u)] for lo, hi, _ in gaps]
        return segs, doors


def _chain(pts: np.ndarray, closed: bool) -> np.ndarray:
    """Segments (K, 4) joining consecutive points (and the last to the first when ``closed``)."""
    ends = np.vstack([pts[1:], pts[:1]]) if closed else pts[1:]
    starts = pts if closed else pts[:-1]
    return np.hstack([starts, ends])
