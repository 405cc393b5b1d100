"""Compiled kernels: :func:`kernel`, numba's ``njit`` as the mapper uses it.

The mapper's per-scan stages are a few dozen numpy calls on arrays of a few hundred elements, so
the calls' overhead (about 1-5 µs each), not the arithmetic, sets their cost. A loop compiled by
numba does the same arithmetic in one call. Only loops whose numpy form is mostly overhead are
compiled; each kernel's docstring says what it replaces.

Compiled code is cached on disk (numba's ``cache=True``): next to the module in ``__pycache__``
when that is writable, else in numba's per-user cache, or wherever ``NUMBA_CACHE_DIR`` points
(the systemd unit sets it to the service's cache directory). A kernel compiles on its first call
in a process without a cache (about a second each). Where no cache directory can be written at
all, the kernels still compile, only not to disk.

numba compiles to machine code at run time, so the process needs memory it can make executable:
the systemd unit cannot set ``MemoryDenyWriteExecute=yes``.
"""

from __future__ import annotations

from collections.abc import Callable

import numba


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
