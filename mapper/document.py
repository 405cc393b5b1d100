"""The map document ``asrmap/map/1``, out and in (shared/design/interfaces.md).

::

    {"schema": "asrmap/map/1", "robot": "pioneer",
     "asrs": [{"id", "created", "origin", "boundary", "edges", "centre", "exits": [{"id", "a", "b", "to"}],
               "duplicate_of", "scans"}],
     "links": [{"from", "exit", "to", "via", "oneway"}],
     "cycles": [{"time", "asr", "matches", "accepted", "iou", "reason"}]}

``created`` (s), ``origin`` (the ASR frame's global pose: m, m, rad); ``boundary``, ``centre`` and
exits in the ASR's own frame (m), boundary counter-clockwise and not closed, ``edges[i]`` labelling
boundary[i] -> boundary[i+1]. Every number is a Python float or int, so ``json`` writes the shortest
repr that reads back to the same float: document -> JSON -> document is exact, and so is
document -> records -> document.

The ASR's ``centre_rule`` is not a document field; on reading it is recovered from the geometry
(``centroid`` when the centre is the polygon's centroid, else ``point_on_surface``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely

from mapper.cycle_params import CycleParams
from mapper.globalmap import CycleRecord, GlobalMap
from mapper.topology import Link
from mapper.types import ASR, EDGE_LABELS, Exit

SCHEMA = "asrmap/map/1"


class DocumentError(ValueError):
    """A map document that does not follow ``asrmap/map/1``; the message names the field."""


@dataclass(slots=True)
class MapDocument:
    """A map document read into records: ASRs in creation order, links, cycle decisions."""

    robot: str = "pioneer"
    asrs: list[ASR] = field(default_factory=list)
    links: list[Link] = field(default_factory=list)
    cycles: list[CycleRecord] = field(default_factory=list)


def _xy(p) -> list[float]:
    return [float(p[0]), float(p[1])]


def asr_to_dict(asr: ASR) -> dict[str, Any]:
    """One ASR as the document (and the ``asrmap/<robot>/asr/<id>`` payload) stores it."""
    return {
        "id": int(asr.id),
        "created": float(asr.created),
        "origin": [float(v) for v in asr.origin],
        "boundary": [_xy(p) for p in np.asarray(asr.boundary, dtype=float)],
        "edges": [str(e) for e in asr.edges],
        "centre": _xy(asr.centre),
        "exits": [
            {"id": e.id, "a": _xy(e.a), "b": _xy(e.b), "to": None if e.to is None else int(e.to)}
            for e in asr.exits
        ],
        "duplicate_of": None if asr.duplicate_of is None else int(asr.duplicate_of),
        "scans": int(asr.scans),
    }


def _need(d: dict, key: str, where: str):
    if key not in d:
        raise DocumentError(f"{where}: missing field {key!r} (asrmap/map/1, see shared/design/interfaces.md)")
    return d[key]


def asr_from_dict(d: dict[str, Any]) -> ASR:
    """Read one ASR record; raises :class:`DocumentError` naming a missing or bad field."""
    where = f"asr {d.get('id', '?')}"
    boundary = _numbers(_need(d, "boundary", where), f"{where}: boundary", "[[x, y], ...] in metres", 2)
    edges = list(_need(d, "edges", where))
    if len(edges) != len(boundary):
        raise DocumentError(f"{where}: {len(edges)} edge labels for {len(boundary)} boundary vertices")
    bad = sorted(set(edges) - set(EDGE_LABELS))
    if bad:
        raise DocumentError(f"{where}: unknown edge labels {bad}; expected {list(EDGE_LABELS)}")
    origin = _point(_need(d, "origin", where), f"{where}: origin", "[x, y, theta] (m, m, rad)", 3)
    centre = _point(_need(d, "centre", where), f"{where}: centre", "[x, y] in metres")
    exits = []
    for k, e in enumerate(_list(d, "exits", where)):
        at = f"{where}: exits[{k}]"
        if not isinstance(e, dict):
            raise DocumentError(f"{at}: expected an object, found {type(e).__name__}")
        a, b = (_point(_need(e, key, at), f"{at}.{key}", "[x, y] in metres") for key in "ab")
        to = _int(e.get("to"), f"{at}.to", none=True)
        exits.append(Exit(_str(_need(e, "id", at), f"{at}.id"), a, b, to))
    return ASR(
        id=_int(_need(d, "id", where), f"{where}: id"),
        created=_float(_need(d, "created", where), f"{where}: created"),
        origin=origin,
        boundary=boundary,
        edges=edges,
        centre=centre,
        centre_rule=_centre_rule(boundary, centre),
        exits=exits,
        duplicate_of=_int(d.get("duplicate_of"), f"{where}: duplicate_of", none=True),
        scans=_int(d.get("scans", 0), f"{where}: scans"),
    )


def _int(value: Any, what: str, none: bool = False) -> int | None:
    """``value`` as an int (an integral float too; never a bool or a string), or None when ``none``
    allows it; else :class:`DocumentError` naming ``what``."""
    if value is None and none:
        return None
    ok = isinstance(value, int) and not isinstance(value, bool)
    if not ok and not (isinstance(value, float) and value.is_integer()):
        raise DocumentError(f"{what}: expected an integer{' or null' if none else ''}, found {value!r}")
    return int(value)


def _float(value: Any, what: str) -> float:
    """``value`` as a finite float (from an int or a float, not a bool); else :class:`DocumentError`."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise DocumentError(f"{what}: expected a finite number, found {value!r}")
    return float(value)


def _str(value: Any, what: str, none: bool = False) -> str | None:
    """``value`` when it is a string (or None when ``none`` allows it); else :class:`DocumentError`."""
    if value is None and none:
        return None
    if not isinstance(value, str):
        raise DocumentError(f"{what}: expected a string{' or null' if none else ''}, found {value!r}")
    return value


def _bool(value: Any, what: str) -> bool:
    if not isinstance(value, bool):
        raise DocumentError(f"{what}: expected true or false, found {value!r}")
    return value


def _numbers(value: Any, what: str, expected: str, width: int) -> np.ndarray:
    """``value`` as finite floats of shape (N, ``width``), else :class:`DocumentError` naming
    ``what`` and the ``expected`` form."""
    try:
        cells = np.array(value, dtype=object)
    except (TypeError, ValueError):
        raise DocumentError(f"{what}: expected {expected}, finite numbers") from None
    # JSON numbers only: float() would take "0" and true (numpy too, in a list with floats)
    if not all(isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in cells.flat):
        raise DocumentError(f"{what}: expected {expected}, finite numbers")
    a = cells.astype(float)
    if a.ndim == 1 and a.size == 0:  # [] : no points
        a = a.reshape(0, width)
    if a.ndim != 2 or a.shape[1] != width or not np.isfinite(a).all():
        raise DocumentError(f"{what}: expected {expected}, finite numbers")
    return a


def _point(value: Any, what: str, expected: str, width: int = 2) -> tuple[float, ...]:
    """One point of ``width`` finite numbers (:func:`_numbers`) as a tuple of Python floats."""
    return tuple(float(v) for v in _numbers([value], what, expected, width)[0])


def _centre_rule(boundary: np.ndarray, centre) -> str:
    if len(boundary) < 3:
        return "centroid"
    c = shapely.Polygon(boundary).centroid
    return (
        "centroid" if c.is_empty or np.hypot(c.x - centre[0], c.y - centre[1]) < 1e-6 else "point_on_surface"
    )


def to_document(
    asrs: list[ASR], links: list[Link], cycles: list[CycleRecord], robot: str = "pioneer"
) -> dict[str, Any]:
    """The ``asrmap/map/1`` dict of these records (ASRs in the order given: creation order)."""
    return {
        "schema": SCHEMA,
        "robot": robot,
        "asrs": [asr_to_dict(a) for a in asrs],
        "links": [ln.to_dict() for ln in links],
        "cycles": [c.to_dict() for c in cycles],
    }


def from_document(doc: dict[str, Any]) -> MapDocument:
    """Read an ``asrmap/map/1`` dict into records; raises :class:`DocumentError` if it is not one."""
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise DocumentError(f"not a map document: schema {got!r}, expected {SCHEMA!r}")
    asrs = _records(doc, "asrs", lambda d, _where: asr_from_dict(d))  # an ASR names itself by id
    ids = {a.id for a in asrs}
    if len(ids) != len(asrs):
        raise DocumentError("asrs: two ASRs with one id")
    for a in asrs:
        if a.duplicate_of is not None and a.duplicate_of not in ids:
            raise DocumentError(f"asr {a.id}: duplicate_of {a.duplicate_of} names an ASR the document "
                                "does not hold")
    links = _records(doc, "links", _link_from_dict)
    for ln in links:
        if ln.src not in ids or ln.dst not in ids:
            raise DocumentError(f"link {ln.src} -> {ln.dst}: names an ASR the document does not hold")
    cycles = _records(doc, "cycles", _cycle_from_dict)
    return MapDocument(str(doc.get("robot", "pioneer")), asrs, links, cycles)


def _list(doc: dict[str, Any], key: str, where: str = "") -> list:
    v = doc.get(key, [])
    if not isinstance(v, list):
        at = f"{where}: {key}" if where else key
        raise DocumentError(f"{at}: expected a list, found {type(v).__name__}")
    return v


def _records(doc: dict[str, Any], key: str, parse) -> list:
    """``parse(d, where)`` of each record of the list ``doc[key]``, ``where`` naming it
    (``links[3]``)."""
    return [_record(f"{key}[{i}]", parse, d) for i, d in enumerate(_list(doc, key))]


def _record(where: str, parse, d: Any):
    """``parse(d, where)``, with any way a record can be malformed (a missing field, a string where a
    number belongs) reported as one :class:`DocumentError` naming the record."""
    if not isinstance(d, dict):
        raise DocumentError(f"{where}: expected an object, found {type(d).__name__}")
    try:
        return parse(d, where)
    except DocumentError:
        raise
    except KeyError as exc:
        raise DocumentError(f"{where}: missing field {exc}") from None
    except (TypeError, ValueError, IndexError, AttributeError) as exc:
        raise DocumentError(f"{where}: {exc}") from None


def _link_from_dict(ln: dict[str, Any], at: str) -> Link:
    # "exit" may be null: a duplicate entered by an exit no view showed.
    return Link(_int(ln["from"], f"{at}.from"), _str(ln["exit"], f"{at}.exit", none=True),
                _int(ln["to"], f"{at}.to"), _str(ln.get("via"), f"{at}.via", none=True),
                _bool(ln.get("oneway", False), f"{at}.oneway"))


def _cycle_from_dict(c: dict[str, Any], at: str) -> CycleRecord:
    return CycleRecord(_float(c["time"], f"{at}.time"), _int(c["asr"], f"{at}.asr"),
                       _int(c["matches"], f"{at}.matches"), _bool(c["accepted"], f"{at}.accepted"),
                       _float(c["iou"], f"{at}.iou"), _str(c["reason"], f"{at}.reason"))


def document_of(gm: GlobalMap, robot: str = "pioneer") -> dict[str, Any]:
    """The document of a whole global map (ASRs in creation order, exits' ``to`` from the topology)."""
    gm.sync_exits()
    asrs = sorted(gm.asrs.values(), key=lambda a: (a.created, a.id))
    return to_document(asrs, gm.topology.links, gm.cycles, robot)


def load_globalmap(doc: dict[str, Any], params: CycleParams | None = None) -> GlobalMap:
    """A :class:`GlobalMap` continuing the map of a document (see :meth:`GlobalMap.restore`)."""
    md = from_document(doc)
    gm = GlobalMap(params)
    gm.restore(md.asrs, md.links, md.cycles)
    return gm
