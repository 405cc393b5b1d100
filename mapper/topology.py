"""The topological map: ASRs as nodes, transitions (ASR a, exit e) <-> (ASR b, exit f) as edges.

A *transition* is directed: crossing exit ``exit`` of ASR ``src`` leads into ASR ``dst``, arriving
through its exit ``via`` (None when the arriving exit is unknown). With it travels ``rel``, the pose
of ``dst``'s frame seen from ``src``'s frame (m, m, rad): for a new ASR that is the robot pose in the
old ASR at the crossing, since the new ASR's frame *is* that pose (method.md §4). Re-entering a known
ASR uses ``rel`` to hand the robot pose over from frame to frame.

A *link* is the record of an edge as the map document stores it (``asrmap/map/1`` ``links``): a
two-way link stands for both transitions; a ``oneway`` link (from a duplicate back to the ASR it was
entered from, method.md §5.5) only for ``from`` -> ``to``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from mapper.se2 import Pose, compose, inverse


@dataclass(frozen=True, slots=True)
class Transition:
    """Crossing ``exit`` of ``src`` leads into ``dst`` via ``via``; ``rel``: dst's frame seen from src's."""

    src: int
    exit: str
    dst: int
    via: str | None
    rel: Pose


@dataclass(slots=True)
class Link:
    """One edge of the map document: ``src`` --exit/via--> ``dst``; both ways unless ``oneway``."""

    src: int
    exit: str | None
    dst: int
    via: str | None
    oneway: bool = False

    def to_dict(self) -> dict:
        return {"from": self.src, "exit": self.exit, "to": self.dst, "via": self.via, "oneway": self.oneway}


class Topology:
    """Transitions between ASRs, their links, duplicates, and neighbourhood queries."""

    def __init__(self) -> None:
        self._out: dict[tuple[int, str], Transition] = {}
        self._adj: dict[int, set[int]] = {}
        self.links: list[Link] = []
        self.entered: dict[int, Transition] = {}
        """The transition that created each ASR (absent for the first ASR and for loaded maps'
        roots); its ``src`` is the ASR the new one was entered from."""
        self.duplicate_of: dict[int, int] = {}

    # -- building -----------------------------------------------------------------------------
    def add_node(self, asr: int) -> None:
        self._adj.setdefault(asr, set())

    def _connect(self, a: int, b: int) -> None:
        self._adj.setdefault(a, set()).add(b)
        self._adj.setdefault(b, set()).add(a)

    def add_creation(self, src: int, exit: str, dst: int, via: str | None, rel: Pose) -> Transition:
        """A new ASR ``dst`` created by crossing ``exit`` of ``src``; its entrance is ``via``."""
        t = self._add(src, exit, dst, via, rel, oneway=False)
        self.entered[dst] = t
        return t

    def add_link(
        self, src: int, exit: str, dst: int, via: str | None, rel: Pose, oneway: bool = False
    ) -> Link:
        """Add an edge. Two-way links also register ``(dst, via) -> src`` unless that exit already
        leads somewhere (an exit keeps its first destination: it is what the robot saw)."""
        self._add(src, exit, dst, via, rel, oneway)
        return self.links[-1]

    def _add(self, src, exit, dst, via, rel, oneway) -> Transition:
        t = Transition(src, exit, dst, via, tuple(float(v) for v in rel))
        self._out[(src, exit)] = t
        if not oneway and via is not None and (dst, via) not in self._out:
            self._out[(dst, via)] = Transition(dst, via, src, exit, inverse(t.rel))
        self.links.append(Link(src, exit, dst, via, oneway))
        self._connect(src, dst)
        return t

    def close_onto(self, dup: int, match: int, match_exit: str | None, rel_src_match: Pose) -> Link | None:
        """Close a cycle: ASR ``dup`` (entered from P through exit e) is a duplicate of ``match``.

        The link P <-> dup becomes one-way (dup -> P: the duplicate serves the direction it was
        entered from), and P's exit e now leads into ``match`` through ``match_exit`` (two-way):
        the old ASR serves traversals through its own exits. ``rel_src_match`` is match's frame
        seen from P's frame. Returns the new link (None when ``dup`` has no known entrance).
        """
        self.duplicate_of[dup] = match
        self.add_node(match)
        self._connect(dup, match)
        entry = self.entered.get(dup)
        if entry is None:
            return None
        for link in self.links:
            if link.src == entry.src and link.exit == entry.exit and link.dst == dup:
                link.src, link.exit, link.dst, link.via = dup, entry.via, entry.src, entry.exit
                link.oneway = True
        del self._out[(entry.src, entry.exit)]
        return self.add_link(entry.src, entry.exit, match, match_exit, rel_src_match)

    def rekey(self, src: int, old: str, new: str) -> Transition:
        """The transition out of ``src`` through exit ``old`` now goes through exit ``new`` (the
        exit that took ``old``'s place when ``src`` was relabelled): its record, its reverse's
        ``via``, its links and ``entered`` where either created an ASR. Returns it."""
        t = self._out.pop((src, old))
        moved = replace(t, exit=new)
        self._out[(src, new)] = moved
        back = self._out.get((t.dst, t.via)) if t.via is not None else None
        if back is not None and back.dst == src and back.via == old:
            renamed = replace(back, via=new)
            self._out[(t.dst, t.via)] = renamed
            if self.entered.get(src) == back:  # src was created through that reverse transition
                self.entered[src] = renamed
        for link in self.links:
            if link.src == src and link.exit == old:
                link.exit = new
            elif link.dst == src and link.via == old:
                link.via = new
        if self.entered.get(t.dst) == t:
            self.entered[t.dst] = moved
        return moved

    # -- queries ------------------------------------------------------------------------------
    def lookup(self, asr: int, exit: str) -> Transition | None:
        """Where crossing ``exit`` of ``asr`` leads (re-entry), or None if unexplored."""
        return self._out.get((asr, exit))

    def out_of(self, asr: int) -> list[Transition]:
        """Every known transition out of ``asr``."""
        return [t for (a, _), t in self._out.items() if a == asr]

    def destinations(self, asr: int) -> dict[str, int]:
        """Exit id -> destination ASR for every known transition out of ``asr``."""
        return {t.exit: t.dst for t in self.out_of(asr)}

    def neighbours(self, asr: int) -> set[int]:
        """ASRs one edge away (any direction, duplicates included)."""
        return set(self._adj.get(asr, ()))

    def within(self, asr: int, hops: int) -> set[int]:
        """ASRs at most ``hops`` edges from ``asr`` (``asr`` itself included)."""
        seen = {asr}
        frontier = deque([(asr, 0)])
        while frontier:
            a, d = frontier.popleft()
            if d == hops:
                continue
            for b in self._adj.get(a, ()):
                if b not in seen:
                    seen.add(b)
                    frontier.append((b, d + 1))
        return seen

    def canonical(self, asr: int) -> int:
        """The original an ASR duplicates (following chains), or itself."""
        return original_of(asr, self.duplicate_of.get)

    def entered_from(self, asr: int) -> int | None:
        t = self.entered.get(asr)
        return None if t is None else t.src


def child_origin(parent_origin: Pose, crossing_pose: Pose) -> Pose:
    """Global pose of a new ASR: the parent's global pose ⊕ the robot pose in the parent's frame
    at the crossing (method.md §4). Both poses (m, m, rad)."""
    return compose(parent_origin, crossing_pose)


def original_of(asr: int, duplicate_of: Callable[[int], int | None]) -> int:
    """The original ASR that ``asr`` duplicates, following chains of duplicates, or ``asr`` itself;
    ``duplicate_of(k)`` is the ASR that k duplicates, or None. A chain that comes round stops."""
    seen = set()
    while asr not in seen and (m := duplicate_of(asr)) is not None:
        seen.add(asr)
        asr = m
    return asr
