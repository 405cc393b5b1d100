"""Where the shared real recorded logs live.

The logs are never copied into the repository: they are read from ``$ASRMAP_DATA`` if set,
otherwise from ``../shared/data`` beside the checkout (where developers and CI have them).
"""

from __future__ import annotations

import os
from pathlib import Path


def data_dir() -> Path:
    """The folder of the shared CARMEN logs; raises FileNotFoundError naming what to set."""
    env = os.environ.get("ASRMAP_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "shared" / "data")
    candidates.append(Path.cwd().parent / "shared" / "data")
    for c in candidates:
        if (c / "SOURCES.md").exists():
            return c
    raise FileNotFoundError(
        "the shared logs were not found: set ASRMAP_DATA to the folder holding intel-raw-first5505.clf.gz "
        f"(looked in {', '.join(str(c) for c in candidates)})"
    )


def log_path(name: str) -> Path:
    """Path of one shared log by file name, e.g. ``intel-raw-first5505.clf.gz``."""
    p = data_dir() / name
    if not p.exists():
        raise FileNotFoundError(f"{p} does not exist (the shared logs are listed in {data_dir()}/SOURCES.md)")
    return p
