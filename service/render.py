"""SVG picture of a map document: the topological map beside the global metric map (the paper's Fig. 1).

Plain SVG text, written by hand (no plotting dependency). Left: the topological map, nodes = ASRs
numbered in creation order, placed at their centres in the global frame so that the graph reads like
the place (a node that would cover one drawn before it, as a duplicate covers the ASR it matched, is
moved aside just far enough that both numbers read); links as lines, one-way links to duplicates
dashed with an arrow, cycle links red.
Right: the global metric map, every ASR polygon in the global frame with its edges coloured by label
(surface black, exit green, unknown grey dashed), exits drawn thick, centres dotted, duplicates
hatched. The y axis points up as in the map (SVG's points down).

With a ``robot`` pose (an ``asrmap/pose/1`` body: ``asr``, ``global`` (x, y, theta: m, m, rad in
the global frame)), the robot is drawn as an arrow on the metric map and its ASR's node ringed.

``render_svg(doc)`` returns the text; ``write_svg(path, doc)`` writes it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np

from mapper.se2 import transform_points
from service.argtypes import write_output

PANEL = 560.0
MARGIN = 30.0
NODE_RADIUS = 8.0  # px, a topological node's circle
NODE_GAP = 2.0 * NODE_RADIUS + 2.0  # px between two nodes' centres at the least
EXIT_STYLE = 'stroke="#1a9a3a" stroke-width="2.5" stroke-opacity="0.5"'
EDGE_STYLE = {
    "surface": 'stroke="#111" stroke-width="1.6"',
    "exit": 'stroke="#1a9a3a" stroke-width="2.2"',
    "unknown": 'stroke="#999" stroke-width="0.9" stroke-dasharray="4 3"',
}


def _global(doc: dict):
    """Per ASR id: boundary (N, 2), centre (2,), exits [(a, b)] in the global frame (m)."""
    out = {}
    for a in doc.get("asrs", []):
        o = tuple(a["origin"])
        b = transform_points(o, np.array(a["boundary"], dtype=float).reshape(-1, 2))
        c = transform_points(o, np.array(a["centre"], dtype=float))[0]
        ex = [transform_points(o, np.array([e["a"], e["b"]], dtype=float)) for e in a.get("exits", [])]
        out[a["id"]] = (b, c, ex)
    return out


class _View:
    """Map metres -> SVG pixels for one panel (uniform scale, y flipped)."""

    def __init__(self, pts: np.ndarray, x0: float):
        lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(2), np.ones(2))
        span = max(float(np.max(hi - lo)), 1e-6)
        self.s = (PANEL - 2 * MARGIN) / span
        self.lo, self.hi, self.x0 = lo, hi, x0

    def __call__(self, p) -> tuple[float, float]:
        return (
            self.x0 + MARGIN + (float(p[0]) - self.lo[0]) * self.s,
            PANEL - MARGIN - (float(p[1]) - self.lo[1]) * self.s + 20.0,
        )

    def path(self, pts) -> str:
        return " ".join(f"{x:.1f},{y:.1f}" for x, y in (self(p) for p in pts))


def _spread(xy: dict[int, tuple[float, float]], gap: float = NODE_GAP) -> dict[int, tuple[float, float]]:
    """Node positions (px) moved apart so that no two lie closer than ``gap``. Nodes are placed in
    id order (creation order); one that lands too near a node already placed goes to the nearest
    free point on rings round its own place (radius ``gap``, ``2 gap``, ...; every 30°, starting
    straight down-right). Deterministic; a node far from every other keeps its place. Placed nodes
    are kept in a grid of ``gap`` cells, so a test looks at 9 cells, not every node."""
    placed: dict[int, tuple[float, float]] = {}
    grid: dict[tuple[int, int], list[tuple[float, float]]] = {}

    def free(x: float, y: float) -> bool:
        i, j = math.floor(x / gap), math.floor(y / gap)
        return all(math.hypot(x - px, y - py) >= gap - 1e-9
                   for di in (-1, 0, 1) for dj in (-1, 0, 1) for px, py in grid.get((i + di, j + dj), ()))

    for k in sorted(xy):
        x0, y0 = xy[k]
        x, y, ring = x0, y0, 0
        while not free(x, y):
            ring += 1
            spots = [(x0 + ring * gap * math.cos(a), y0 + ring * gap * math.sin(a))
                     for a in (math.radians(45.0 + 30.0 * i) for i in range(12))]
            x, y = next((q for q in spots if free(*q)), (x, y))
        placed[k] = (x, y)
        grid.setdefault((math.floor(x / gap), math.floor(y / gap)), []).append((x, y))
    return placed


def _cycle_links(doc: dict, dup: dict[int, int]) -> set[tuple[int, int]]:
    """Links (from, to) that closed a cycle: P -> M where a duplicate of M (``dup``: duplicate ->
    original) has a one-way link to P."""
    out = set()
    for ln in doc.get("links", []):
        if ln.get("oneway", False) and ln["from"] in dup:
            out.add((ln["to"], dup[ln["from"]]))
    return out


def _line(p, q, style: str, title: str | None = None) -> str:
    body = f"><title>{escape(title)}</title></line>" if title else "/>"
    return f'<line x1="{p[0]:.1f}" y1="{p[1]:.1f}" x2="{q[0]:.1f}" y2="{q[1]:.1f}" {style}{body}'


def robot_pose(robot: Any) -> tuple[int | None, tuple[float, float, float] | None]:
    """(ASR id, global pose) of an ``asrmap/pose/1`` body; None for what is missing or malformed
    (a pose from another version is not drawn rather than failing the picture)."""
    if not isinstance(robot, dict):
        return None, None
    asr = robot.get("asr") if isinstance(robot.get("asr"), int) else None
    g = robot.get("global")
    ok = (isinstance(g, list | tuple) and len(g) == 3
          and all(isinstance(v, int | float) and math.isfinite(v) for v in g))
    return asr, (float(g[0]), float(g[1]), float(g[2])) if ok else None


def render_svg(doc: dict, title: str | None = None, robot: dict | None = None) -> str:
    """The SVG text of an ``asrmap/map/1`` document, with the robot at ``robot`` (an
    ``asrmap/pose/1`` body) when given (see module docstring)."""
    geo = _global(doc)
    pts = np.concatenate([g[0] for g in geo.values()]) if geo else np.zeros((0, 2))
    left, right = _View(pts, 0.0), _View(pts, PANEL)
    dups = {a["id"]: a["duplicate_of"] for a in doc.get("asrs", []) if a.get("duplicate_of") is not None}
    cycle_links = _cycle_links(doc, dups)
    w, h = 2 * PANEL, PANEL + 40
    o = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0f}" height="{h:.0f}"'
        f' viewBox="0 0 {w:.0f} {h:.0f}" font-family="sans-serif">',
        "<defs>",
        '<marker id="arrow" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7"'
        ' orient="auto">'
        '<path d="M0,0 L10,5 L0,10 z" fill="#555"/></marker>',
        '<pattern id="hatch" width="6" height="6" patternUnits="userSpaceOnUse"'
        ' patternTransform="rotate(45)">'
        '<line x1="0" y1="0" x2="0" y2="6" stroke="#d08a2a" stroke-width="1.5"/></pattern>',
        "</defs>",
        f'<rect width="{w:.0f}" height="{h:.0f}" fill="white"/>',
        f"<title>{escape(title or 'asrmap: ' + str(doc.get('robot', '')))}</title>",
    ]
    accepted = sum(1 for c in doc.get("cycles", []) if c.get("accepted"))
    o.append(
        f'<text x="10" y="18" font-size="14">topological map: {len(geo)} ASRs, {len(doc.get("links", []))}'
        f" links, {accepted} cycles</text>"
    )
    o.append(f'<text x="{PANEL + 10:.0f}" y="18" font-size="14">global metric map (m, global frame)</text>')
    o.append(f'<line x1="{PANEL:.0f}" y1="0" x2="{PANEL:.0f}" y2="{h:.0f}" stroke="#ccc"/>')

    # Global metric map.
    edges_of = {a["id"]: a["edges"] for a in doc["asrs"]}
    for k, (b, c, ex) in geo.items():
        fill = 'fill="url(#hatch)" fill-opacity="0.5"' if k in dups else 'fill="#7aa6d8" fill-opacity="0.18"'
        o.append(f'<polygon points="{right.path(b)}" {fill} stroke="none"><title>ASR {k}</title></polygon>')
        labels = edges_of[k]
        for i, lab in enumerate(labels):
            o.append(
                _line(right(b[i]), right(b[(i + 1) % len(b)]), EDGE_STYLE.get(lab, EDGE_STYLE["unknown"]))
            )
        for seg in ex:
            o.append(_line(right(seg[0]), right(seg[1]), EXIT_STYLE))
        x, y = right(c)
        o.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.5" fill="#c0392b"/>')
        # A duplicate's centre lies near its original's: its number goes below the dot, not above.
        ty = y + 11 if k in dups else y - 3
        o.append(f'<text x="{x + 3:.1f}" y="{ty:.1f}" font-size="9" fill="#333">{k}</text>')

    robot_asr, robot_at = robot_pose(robot)
    if robot_at is not None:
        x, y, th = robot_at
        tip = (x + 0.45 * math.cos(th), y + 0.45 * math.sin(th))
        back = [(x + 0.25 * math.cos(th + a), y + 0.25 * math.sin(th + a)) for a in (2.4, -2.4)]
        o.append(f'<polygon id="robot" points="{right.path([tip, back[0], back[1]])}" fill="#8e44ad"'
                 f' stroke="#3b1a47" stroke-width="1"><title>robot at ({x:.2f}, {y:.2f}) m,'
                 f' {math.degrees(th):.0f}° (global frame)</title></polygon>')

    # Topological map.
    node = _spread({k: left(c) for k, (_, c, _) in geo.items()})
    for ln in doc.get("links", []):
        if ln["from"] not in geo or ln["to"] not in geo:
            continue
        (x1, y1), (x2, y2) = node[ln["from"]], node[ln["to"]]
        if ln.get("oneway", False):  # optional in the document: two-way
            # Stop short of the node so the arrow head shows.
            d = math.hypot(x2 - x1, y2 - y1) or 1.0
            x2, y2 = x2 - 9 * (x2 - x1) / d, y2 - 9 * (y2 - y1) / d
            style = 'stroke="#555" stroke-width="1.2" stroke-dasharray="5 3" marker-end="url(#arrow)"'
        elif (ln["from"], ln["to"]) in cycle_links or (ln["to"], ln["from"]) in cycle_links:
            style = 'stroke="#c0392b" stroke-width="2.4"'
        else:
            style = 'stroke="#333" stroke-width="1.6"'
        o.append(_line((x1, y1), (x2, y2), style))
    for k, m in dups.items():
        if k in geo and m in geo:
            dashed = 'stroke="#c0392b" stroke-width="1" stroke-dasharray="2 2"'
            o.append(_line(node[k], node[m], dashed, f"ASR {k} duplicates ASR {m}"))
    for k in geo:
        x, y = node[k]
        ring = 'stroke="#d08a2a" stroke-width="2.5"' if k in dups else 'stroke="#1f4e79" stroke-width="1.5"'
        if k == robot_asr:  # the robot is here
            o.append(f'<circle id="robot-asr" cx="{x:.1f}" cy="{y:.1f}" r="{NODE_RADIUS + 3:g}"'
                     ' fill="none" stroke="#8e44ad" stroke-width="3"/>')
        o.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{NODE_RADIUS:g}" fill="white" {ring}/>')
        o.append(f'<text x="{x:.1f}" y="{y + 3:.1f}" font-size="8" text-anchor="middle">{k}</text>')

    legend = [
        ("#111", "surface"),
        ("#1a9a3a", "exit"),
        ("#999", "unknown"),
        ("#c0392b", "cycle link / duplicate"),
        ("#d08a2a", "duplicate ASR"),
        ("#555", "one-way link (dashed, arrow)"),
    ]
    if robot_at is not None or robot_asr is not None:
        legend.append(("#8e44ad", "robot"))
    x = 10.0
    for colour, text in legend:  # each entry as wide as its text (about 6.2 px a character at 11 px)
        o.append(f'<line x1="{x:.0f}" y1="{h - 14}" x2="{x + 20:.0f}" y2="{h - 14}" stroke="{colour}"'
                 ' stroke-width="3"/>')
        o.append(f'<text x="{x + 25:.0f}" y="{h - 10}" font-size="11">{escape(text)}</text>')
        x += 25 + 6.2 * len(text) + 30
    o.append("</svg>")
    return "\n".join(o) + "\n"


def write_svg(path: str | Path, doc: dict, title: str | None = None, robot: dict | None = None) -> Path:
    """Write :func:`render_svg` of ``doc`` (and ``robot``) to ``path``; returns the path."""
    p = Path(path)
    write_output(p, render_svg(doc, title, robot))
    return p
