"""Events the mapper returns from ``add_odometry``/``add_scan``: small frozen dataclasses.

``to_dict()`` gives the JSON payload published on ``asrmap/<robot>/event`` (schema
``asrmap/event/1``); ``asr_updated`` is not an event on that key: the service answers it by
publishing the ASR itself on ``asrmap/<robot>/asr/<id>``. Times in seconds (the scan clock),
positions in metres, angles in radians; the frame of each field is named in its class.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

SCHEMA = "asrmap/event/1"


def _plain(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return [_plain(i) for i in v]
    if hasattr(v, "item"):  # numpy scalar
        return v.item()
    return v


@dataclass(frozen=True, slots=True)
class Event:
    kind: ClassVar[str] = "event"
    t: float

    def to_dict(self) -> dict[str, Any]:
        d = {"schema": SCHEMA, "event": self.kind}
        d.update({f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)})
        return d


@dataclass(frozen=True, slots=True)
class AsrCreated(Event):
    """A new ASR; ``origin`` is its frame's pose in the global frame; ``entered_from`` the previous ASR."""

    kind: ClassVar[str] = "asr_created"
    asr: int
    origin: tuple[float, float, float]
    entered_from: int | None = None


@dataclass(frozen=True, slots=True)
class AsrUpdated(Event):
    """ASR ``asr`` grew or changed (its boundary, exits or centre); ``area`` in m²."""

    kind: ClassVar[str] = "asr_updated"
    asr: int
    area: float
    scans: int


@dataclass(frozen=True, slots=True)
class ExitCrossed(Event):
    """The robot left ASR ``from_asr`` through exit ``exit`` into ``to_asr`` (``new``: just created)."""

    kind: ClassVar[str] = "exit_crossed"
    from_asr: int
    exit: str
    to_asr: int
    via: str | None
    new: bool


@dataclass(frozen=True, slots=True)
class CycleDecision(Event):
    """A cycle check's verdict on ASR ``asr`` against the earlier ASR ``matches``.

    ``centre``/``match_centre``: both centres in the global frame (m); ``iou``: overlap of the two
    global polygons; ``reason``: which rule decided (``centre-crosscheck``, ``hindsight``, ...).
    """

    asr: int
    matches: int
    centre: tuple[float, float]
    match_centre: tuple[float, float]
    iou: float
    reason: str
    accepted: bool


@dataclass(frozen=True, slots=True)
class CycleDetected(CycleDecision):
    """A cycle closed: ``asr`` was accepted as a revisit of ``matches``."""

    kind: ClassVar[str] = "cycle_detected"
    accepted: bool = True


@dataclass(frozen=True, slots=True)
class CycleRejected(CycleDecision):
    """A candidate match of ``asr`` with ``matches`` that was rejected, and why (``reason``)."""

    kind: ClassVar[str] = "cycle_rejected"
    accepted: bool = False


@dataclass(frozen=True, slots=True)
class MapRealigned(Event):
    """The global poses were relaxed by the ASR pose graph; ``moved`` = largest origin shift (m)."""

    kind: ClassVar[str] = "map_realigned"
    asrs: int
    constraints: int
    moved: float
    residual: float
