"""What the explorer reads and what it decides: the mapper's view (:class:`MapView`: ASRs in their own
frames with their global origins, links, the current ASR, the robot pose in its frame), the planner's
:class:`Goal` and its :class:`Memory` of what it tried."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from mapper.se2 import Pose
from mapper.topology import original_of
from mapper.types import ASR


@dataclass(frozen=True, slots=True)
class LinkRef:
    """A topological link (``asrmap/map/1`` ``links``): crossing ``exit`` of ``src`` leads into ``dst``
    through ``via``; both ways unless ``oneway``."""

    src: int
    exit: str | None
    dst: int
    via: str | None = None
    oneway: bool = False


@dataclass(frozen=True)
class MapView:
    """The mapper's state as the explorer needs it: the current ASR id (None before the first
    scan), the robot pose in that ASR's frame, every ASR record by id, and the links."""

    current: int | None
    pose: Pose
    asrs: Mapping[int, ASR]
    links: Sequence[LinkRef] = ()

    @classmethod
    def from_document(cls, doc: dict[str, Any], current: int | None, pose: Pose) -> MapView:
        """From an ``asrmap/map/1`` document (as ``Mapper.document()`` or the Zenoh map query give)."""
        from mapper.document import from_document

        md = from_document(doc)
        return cls(current, pose, {a.id: a for a in md.asrs}, links_of(md.links))


def links_of(links: Iterable[Any]) -> list[LinkRef]:
    """:class:`LinkRef` from link objects (``src``/``exit``/``dst``/``via``/``oneway``) or document dicts."""
    out = []
    for ln in links:
        if isinstance(ln, dict):
            out.append(LinkRef(int(ln["from"]), ln.get("exit"), int(ln["to"]), ln.get("via"),
                               bool(ln.get("oneway", False))))
        else:
            out.append(LinkRef(int(ln.src), ln.exit, int(ln.dst), ln.via, bool(ln.oneway)))
    return out


@dataclass(frozen=True, slots=True)
class Goal:
    """One step of exploration, in the frame of ASR ``asr``.

    ``kind``: ``unknown`` (go to ``target``, then face ``look_at``), ``exit`` (an unexplored exit),
    ``close`` (an exit into known space not linked to it: ``ExploreParams.close_loops``),
    ``backtrack`` (a known exit on the way to ``path[-1]``), ``settle`` (just crossed into ``asr``:
    on to ``target``, the point beyond the exit), ``goto`` (no route on the topological map: across
    the ASR towards the nearest unexplored exit of any ASR, ``exit`` that ASR's), ``done`` or ``wait``
    (no ASR yet).
    For exits: ``target`` is the staging point inside, ``through`` the point beyond the exit.
    """

    kind: str
    asr: int | None = None
    target: tuple[float, float] | None = None
    look_at: tuple[float, float] | None = None
    exit: str | None = None
    through: tuple[float, float] | None = None
    path: tuple[int, ...] = ()
    exit_mid: tuple[float, float] | None = None

    @property
    def key(self) -> tuple:
        """What makes two goals the same goal (kind, ASR, exit, place looked at)."""
        return (self.kind, self.asr, self.exit, self.look_at)


@dataclass
class Memory:
    """What the planner has tried: unknown regions looked at (per ASR, points in its frame) and
    exits that could not be crossed, by ``(asr, exit id)`` and by midpoint (per ASR, its frame),
    since the mapper may renumber the exits of an ASR that grows."""

    looked: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    failed_exits: set[tuple[int, str]] = field(default_factory=set)
    failed_at: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    retries: int = 0
    #: Unknown regions retired by a look from afar (:meth:`Planner.observe`), per ASR (its frame),
    #: and whether the round that visits them (``ExploreParams.visit_round``) has begun.
    far: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    visiting: bool = False
    #: Whether the last round, through the side openings of linked exits
    #: (``ExploreParams.side_openings``), has begun.
    side_round: bool = False
    #: Exits seen shut (a surface right behind them, :meth:`Planner.shut_exits`), by midpoint per
    #: ASR (its frame); not retried: a wall does not move.
    shut_at: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    #: Exits the robot crossed into an ASR already known, by midpoint per ASR (its frame): they
    #: lead into mapped space, whether or not the mapper linked them; not retried.
    crossed_at: dict[int, list[tuple[float, float]]] = field(default_factory=dict)
    #: How many exits of each ASR the robot crossed to close a loop (``ExploreParams.close_loops``,
    #: at most ``close_per_asr``); and the ASRs those crossings made, each with its place in the
    #: chain of such crossings (1 for the first; ``ExploreParams.close_chain``).
    closing_from: dict[int, int] = field(default_factory=dict)
    closing_made: dict[int, int] = field(default_factory=dict)


def place_of(view: MapView, asr_id: int) -> int:
    """The original ASR that ``asr_id`` duplicates in ``view`` (itself if none): one place."""
    return original_of(asr_id, lambda k: a.duplicate_of if (a := view.asrs.get(k)) is not None else None)
