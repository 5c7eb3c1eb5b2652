"""Memory for the tile stores: address space reserved up front, pages resident only once written."""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["reserve_float64"]


def reserve_float64(shape: tuple[int, ...]) -> np.ndarray | None:
    """float64 array of `shape` over reserved address space: anonymous memory mapped without reserving
    swap, so a page becomes resident only when first written. The store never has to be copied to
    grow (no stall, no transient double) until the reservation is used up. None if refused."""
    size = int(np.prod(shape)) * 8
    try:
        flags = mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | getattr(mmap, "MAP_NORESERVE", 0)
        buf = mmap.mmap(-1, size, flags=flags, prot=mmap.PROT_READ | mmap.PROT_WRITE)
    except (OSError, ValueError, AttributeError):
        return None
    return np.frombuffer(buf, dtype=np.float64).reshape(shape)
