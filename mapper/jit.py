"""Compiled kernels: :func:`kernel`, numba's ``njit`` as the mapper uses it.

The mapper's per-scan stages are a few dozen numpy calls on arrays of a few hundred elements, so
the calls' overhead (about 1-5 µs each), not the arithmetic, sets their cost. A loop compiled by
numba does the same arithmetic in one call. Only loops whose numpy form is mostly overhead are
compiled; each kernel's docstring says what it replaces.

Compiled code is cached on disk (numba's ``cache=True``) under ``NUMBA_CACHE_DIR`` (the systemd unit
sets it to the service's cache directory), else ``$XDG_CACHE_HOME/asrmap/numba`` (by default
``~/.cache/asrmap/numba``), in a subdirectory named by a hash of this package's sources
(:func:`cache_dir`, ``asrmap-<hash>``). numba checks a cached kernel only against its own source
file, so a kernel that calls another module's kernel kept running the old callee after only the
callee's module changed (seen: ``asr_builder._pairs_in_boxes`` with an edited
``exits.closest_point``); one cache per version of the sources cannot. Caches of other versions
(directories named ``asrmap-*`` beside this one; nothing else in a shared ``NUMBA_CACHE_DIR``)
unused for a week are removed. The price: an edit of any mapper module compiles every kernel again
once (about 13 s), not only that module's. A kernel compiles on its first call in a process without
a cache (about a second each). Where no cache directory can be written at all, the kernels still
compile, only not to disk.

numba compiles to machine code at run time, so the process needs memory it can make executable:
the systemd unit cannot set ``MemoryDenyWriteExecute=yes``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numba

_KEEP_OTHERS = 7 * 86400.0  # s: how long an unused cache of other sources is kept
_PREFIX = "asrmap-"  # only directories named so are ever removed (NUMBA_CACHE_DIR may be shared)


def cache_dir(package: Path | None = None) -> Path:
    """Where the kernels of these sources are cached: ``NUMBA_CACHE_DIR`` (or
    ``$XDG_CACHE_HOME/asrmap/numba``, ``~/.cache/asrmap/numba``) / ``asrmap-`` and the first 16 hex
    digits of a SHA-256 over the ``.py`` files (names and contents) of ``package`` (default: this
    one's)."""
    here = package or Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(here.glob("*.py")):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "asrmap", "numba")
    return Path(base) / f"{_PREFIX}{h.hexdigest()[:16]}"


def prune_caches(keep: Path, now: float | None = None) -> list[Path]:
    """Remove the caches of other versions beside ``keep`` unused for a week: only directories
    named ``asrmap-*`` (a shared ``NUMBA_CACHE_DIR`` keeps everything else). Returns those removed."""
    now = time.time() if now is None else now
    gone = []
    for other in keep.parent.iterdir():
        if (other != keep and other.name.startswith(_PREFIX) and other.is_dir()
                and now - other.stat().st_mtime > _KEEP_OTHERS):
            shutil.rmtree(other, ignore_errors=True)
            gone.append(other)
    return gone


def _use_cache_dir() -> None:
    """Point numba at :func:`cache_dir` and drop other versions' caches unused for a week; any
    failure (an unwritable directory) leaves numba to find a place itself, or none."""
    try:
        d = cache_dir()
        d.mkdir(parents=True, exist_ok=True)
        os.utime(d)  # in use: keep
        numba.config.CACHE_DIR = str(d)
        prune_caches(d)
    except OSError:
        pass


_use_cache_dir()


def kernel(fn: Callable | None = None, *, inline: bool = False) -> Callable:
    """``fn`` compiled in nopython mode (no Python objects inside; numba's default float
    semantics, no fast-math), cached on disk where a cache directory can be written. With
    ``inline`` (``@kernel(inline=True)``), other kernels take its body in place of a call: for a
    small kernel called in an inner loop with arrays, whose every call would otherwise count
    references to each array passed."""
    if fn is None:
        return lambda f: kernel(f, inline=inline)
    opts = {"inline": "always"} if inline else {}
    try:
        return numba.njit(cache=True, **opts)(fn)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available"
        return numba.njit(cache=False, **opts)(fn)
