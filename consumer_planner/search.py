"""Optimal path search on an 8-connected cost grid.

Path cost (the one definition used everywhere in consumer_planner): a path is a sequence of cells
p_0 .. p_k, each step to one of the 8 neighbours; a step a -> b costs

    len(a, b) * (cost[a] + cost[b]) / 2,   len = res [m] straight, res * sqrt(2) [m] diagonal,

and the path cost is the sum over its steps. Equivalently, each cell contributes `cost * weight` with
weight = half the length of the steps entering and leaving it (`compare.cell_weights`). Cells with a
non-finite cost are impassable; diagonal steps may pass between two impassable cells that touch at a
corner (the same graph as scikit-image's `MCP_Geometric`, `fully_connected=True`).

The search runs in a small C kernel (`_native`, built on first use): an exact Dijkstra with a bucket
queue whose bucket width is the cheapest possible step (res x min cost), so every cell of the lowest
bucket is final and a push costs O(1); when cells may cost 0 or the cost range exceeds 2^20 buckets,
A* on a 4-ary heap with the consistent heuristic `min(cost) x octile distance`. Both stop at the goal.
Without a C compiler it falls back to scikit-image's `MCP_Geometric` (same optimum, ~6x slower).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Literal

import numpy as np

from consumer_planner import _native
from consumer_planner.errors import PlannerError

__all__ = ["GridPath", "METHODS", "nearest_passable", "plan_path", "step_lengths"]

METHODS = ("auto", "native", "skimage")
_MAX_BUCKETS = 1 << 20  # above this cost range (max/min cell cost) the heap search is used
Method = Literal["auto", "native", "skimage"]


@dataclass(frozen=True, eq=False)
class GridPath:
    """An optimal path: `cells` (k, 2) int (row, col) from start to goal; `cost` as defined above."""

    cells: np.ndarray
    cost: float
    method: str


def step_lengths(cells: np.ndarray, res: float) -> np.ndarray:
    """Lengths [m] of the k-1 steps of a cell path (k, 2); res for straight, res*sqrt(2) for diagonal."""
    d = np.abs(np.diff(np.asarray(cells), axis=0))
    return np.where((d[:, 0] > 0) & (d[:, 1] > 0), res * np.sqrt(2.0), res * (d.sum(axis=1) > 0))


def _check_cell(cost: np.ndarray, cell: tuple[int, int], name: str) -> int:
    h, w = cost.shape
    r, c = int(cell[0]), int(cell[1])
    if not (0 <= r < h and 0 <= c < w):
        raise PlannerError(f"{name} cell (row {r}, col {c}) is outside the grid of {h} x {w} cells")
    if not np.isfinite(cost[r, c]):
        raise PlannerError(f"{name} cell (row {r}, col {c}) is impassable (cost {cost[r, c]})")
    return r * w + c


def nearest_passable(cost: np.ndarray, cell: tuple[int, int], radius_cells: float) -> tuple[int, int] | None:
    """The passable cell (finite cost) nearest to `cell` (row, col) within `radius_cells`, or None; `cell`
    itself when it is passable. Like a navigation stack's goal tolerance: a goal on a cell the map forbids
    (a robot fell there) is replaced by the closest cell a robot may stand on."""
    h, w = cost.shape
    r0, c0 = int(cell[0]), int(cell[1])
    if 0 <= r0 < h and 0 <= c0 < w and np.isfinite(cost[r0, c0]):
        return r0, c0
    k = int(np.floor(radius_cells))
    rr, cc = np.mgrid[max(0, r0 - k):min(h, r0 + k + 1), max(0, c0 - k):min(w, c0 + k + 1)]
    d2 = (rr - r0) ** 2 + (cc - c0) ** 2
    ok = np.isfinite(cost[rr, cc]) & (d2 <= radius_cells**2)
    if not ok.any():
        return None
    i = int(np.argmin(np.where(ok, d2, np.iinfo(np.int64).max)))
    return int(rr.ravel()[i]), int(cc.ravel()[i])


def plan_path(
    cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int], res: float, method: Method = "auto"
) -> GridPath | None:
    """Cheapest 8-connected path from `start` to `goal` (row, col) over `cost` (h, w) [1/m], cell size
    `res` [m]; None when the goal cannot be reached. Raises PlannerError for an endpoint outside the grid
    or on an impassable cell, or a negative cost."""
    if method not in METHODS:
        raise PlannerError(f"no search method {method!r}; methods: {', '.join(METHODS)}")
    cost = np.ascontiguousarray(cost, dtype=np.float64)
    if cost.ndim != 2 or cost.size == 0:
        raise PlannerError(f"cost grid must be a non-empty 2-D array, got shape {cost.shape}")
    s = _check_cell(cost, start, "start")
    g = _check_cell(cost, goal, "goal")
    finite = cost[np.isfinite(cost)]
    if (finite < 0).any():
        raise PlannerError(f"cell costs must be >= 0 (min {finite.min()}); use inf for impassable")
    lib = _native.load() if method in ("auto", "native") else None
    if method == "native" and lib is None:
        raise PlannerError("the native search kernel cannot be built here (no C compiler); use 'skimage'")
    if lib is not None:
        return _native_path(lib, cost, s, g, res, float(finite.min()), float(finite.max()))
    return _skimage_path(cost, start, goal, res)


def _native_path(
    lib: ctypes.CDLL, cost: np.ndarray, s: int, g: int, res: float, cmin: float, cmax: float
) -> GridPath | None:
    h, w = cost.shape
    pw = w + 2  # the kernel wants a border of impassable cells instead of bounds checks
    padded = np.full((h + 2, pw), np.inf)
    padded[1:-1, 1:-1] = cost
    n = padded.size
    gbuf = np.empty(n, np.float64)
    parent = np.empty(n, np.int64)
    closed = np.empty(n, np.uint8)
    out = np.empty(n, np.int64)
    total = ctypes.c_double(0.0)
    ptr = ctypes.c_void_p
    ps = (s // w + 1) * pw + s % w + 1
    pg = (g // w + 1) * pw + g % w + 1
    bufs = (ptr(gbuf.ctypes.data), ptr(parent.ctypes.data), ptr(closed.ctypes.data), ptr(out.ctypes.data))
    delta = res * cmin * (1.0 - 1e-9)  # bucket width <= the cheapest step (a straight one)
    nbuckets = int(np.ceil(res * np.sqrt(2.0) * cmax / delta)) + 2 if delta > 0 else 0
    if 0 < nbuckets <= _MAX_BUCKETS:
        m = lib.dial8(ptr(padded.ctypes.data), h + 2, pw, float(res), ps, pg, delta, nbuckets, *bufs,
                      ctypes.byref(total))  # fmt: skip
    else:  # zero-cost cells or a huge cost range: A* on a heap
        m = lib.astar8(
            ptr(padded.ctypes.data), h + 2, pw, float(res), ps, pg, cmin, *bufs, ctypes.byref(total)
        )
    if m < 0:
        raise MemoryError("search heap allocation failed")
    if m == 0:
        return None
    idx = out[:m][::-1]
    cells = np.stack([idx // pw - 1, idx % pw - 1], axis=1)
    return GridPath(cells, float(total.value), "native")


def _skimage_path(
    cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int], res: float
) -> GridPath | None:
    from skimage.graph import MCP_Geometric

    grid = np.where(np.isfinite(cost), cost, -1.0)  # MCP: negative = impassable
    mcp = MCP_Geometric(grid, fully_connected=True)
    cum, _ = mcp.find_costs([tuple(start)], [tuple(goal)])
    total = cum[tuple(goal)]
    if not np.isfinite(total):
        return None
    cells = np.asarray(mcp.traceback(tuple(goal)), dtype=np.int64)
    return GridPath(cells, float(total) * res, "skimage")
