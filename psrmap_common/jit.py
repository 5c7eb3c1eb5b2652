"""numba's first-run compile, said out loud: which compiled kernels have no machine code in the on-disk cache yet.

Kernels are `njit(cache=True)`: the first process after an install (or after a kernel's source changed)
compiles them, tens of seconds on a small machine, and every later process loads the cached code. `uncached`
names the kernels that would compile now, so a command can print one line before that silent wait (or compile
them ahead at a point of its choosing). It reads numba's cache index; numba is imported only by the callers'
kernel modules.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

__all__ = ["COMPILE_NOTICE", "uncached"]

COMPILE_NOTICE = (
    "compiling numba kernels once for this install (the first run after an install or upgrade; up to a minute "
    "on a small machine, cached for every later run)"
)


def uncached(dispatchers: Iterable[Any]) -> list[str]:
    """The names of the `njit(cache=True)` dispatchers whose cache holds no compiled code for their current
    source (so their first call compiles)."""
    out = []
    for d in dispatchers:
        try:
            index = d._cache._cache_file._load_index()  # {} when missing or stale (the source changed)
        except Exception:  # a numba without this layout: say nothing rather than guess
            continue
        if not index:
            out.append(d.__name__)
    return out
