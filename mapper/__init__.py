"""The method of Jefferies, Cosgrove, Baker & Yeap: pure computation, no I/O, no threads.

``from mapper import Mapper, MapperParams, Odometry, Scan`` (shared/design/interfaces.md). The
names are resolved lazily so that importing a light submodule (``mapper.se2``, ``mapper.types``)
does not pay for filterpy, which pulls in scipy.stats (about a second).
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Mapper": "mapper.mapper",
    "MapperParams": "mapper.params",
    "Odometry": "mapper.types",
    "Scan": "mapper.types",
    "ASR": "mapper.types",
    "Exit": "mapper.types",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'mapper' has no attribute {name!r}")
