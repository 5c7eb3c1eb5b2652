"""Optimal path search on an 8-connected cost grid.

Path cost (the one definition the planner and the scout's detours use): a path is a sequence of cells
p_0 .. p_k, each step to one of the 8 neighbours; a step a -> b costs

    len(a, b) * (cost[a] + cost[b]) / 2,   len = res [m] straight, res * sqrt(2) [m] diagonal,

and the path cost is the sum over its steps. Equivalently, each cell contributes `cost * weight` with
weight = half the length of the steps entering and leaving it (`compare.cell_weights`). Cells with a
non-finite cost are impassable; diagonal steps may pass between two impassable cells that touch at a
corner (the same graph as scikit-image's `MCP_Geometric`, `fully_connected=True`).

The search runs in compiled kernels (`kernels`, numba, cached on disk after the first compile): an
exact Dijkstra with a bucket queue whose bucket width is the cheapest possible step (res x min cost), so
every cell of the lowest bucket is final and a push costs O(1); when cells may cost 0 or the cost range
needs more than 2^16 buckets, A* on a binary heap with the consistent heuristic `min(cost) x octile distance`.
Both stop at the goal. Every argument is checked here before a kernel runs (the kernels do no bounds
checks). `method="skimage"` runs scikit-image's `MCP_Geometric` instead (same optimum, ~6x slower), the
independent reference the tests compare against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from psrmap_common.pathsearch import kernels
from psrmap_common.pathsearch.errors import PathSearchError

__all__ = ["GridPath", "METHODS", "Method", "nearest_passable", "plan_path", "step_lengths"]

METHODS = ("auto", "compiled", "skimage")
_MAX_BUCKETS = 1 << 16  # above this many buckets (cost range max/min x 1.4) the heap search is used
Method = Literal["auto", "compiled", "skimage"]
_MAX_CELLS = (1 << 31) - 1  # the kernels keep parents as int32


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
        raise PathSearchError(f"{name} cell (row {r}, col {c}) is outside the grid of {h} x {w} cells")
    if not np.isfinite(cost[r, c]):
        raise PathSearchError(f"{name} cell (row {r}, col {c}) is impassable (cost {cost[r, c]})")
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
    rr, cc = np.mgrid[max(0, r0 - k) : min(h, r0 + k + 1), max(0, c0 - k) : min(w, c0 + k + 1)]
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
    `res` [m]; None when the goal cannot be reached. Raises PathSearchError for an endpoint outside the grid
    or on an impassable cell, or a negative cost."""
    if method not in METHODS:
        raise PathSearchError(f"no search method {method!r}; methods: {', '.join(METHODS)}")
    cost = np.ascontiguousarray(cost, dtype=np.float64)
    if cost.ndim != 2 or cost.size == 0:
        raise PathSearchError(f"cost grid must be a non-empty 2-D array, got shape {cost.shape}")
    s = _check_cell(cost, start, "start")
    g = _check_cell(cost, goal, "goal")
    try:
        res = float(res)
    except (TypeError, ValueError):
        raise PathSearchError(f"cell size res must be a number > 0 m, got {res!r}") from None
    if not (math.isfinite(res) and res > 0):
        raise PathSearchError(f"cell size res must be a finite number > 0 m, got {res!r}")
    if (cost.shape[0] + 2) * (cost.shape[1] + 2) > _MAX_CELLS:
        raise PathSearchError(f"cost grid of {cost.shape} cells is too large; at most {_MAX_CELLS} cells")
    # the kernels want a border of impassable cells instead of bounds checks, impassable cells closed
    flat, closed, cmin, cmax, neg = kernels.pad(cost)
    if neg < 0:
        raise PathSearchError(f"cell costs must be >= 0 (min {neg}); use inf for impassable")
    if method == "skimage":
        return _skimage_path(cost, start, goal, res)
    return _compiled_path(flat, closed, cost.shape, s, g, res, cmin, cmax)


def _compiled_path(
    flat: np.ndarray,
    closed: np.ndarray,
    shape: tuple[int, int],
    s: int,
    g: int,
    res: float,
    cmin: float,
    cmax: float,
) -> GridPath | None:
    h, w = shape
    pw = w + 2
    out = np.empty(flat.size, np.int64)
    total = np.zeros(1)
    ps = (s // w + 1) * pw + s % w + 1
    pg = (g // w + 1) * pw + g % w + 1
    delta = res * cmin * (1.0 - 1e-9)  # bucket width <= the cheapest step (a straight one)
    nbuckets = int(np.ceil(res * np.sqrt(2.0) * cmax / delta)) + 2 if delta > 0 else 0
    if 0 < nbuckets <= _MAX_BUCKETS:
        m = kernels.dial8(flat, pw, res, ps, pg, delta, nbuckets, closed, out, total)
    else:  # zero-cost cells or a huge cost range: A* on a heap
        m = kernels.astar8(flat, pw, res, ps, pg, cmin, closed, out, total)
    if m == 0:
        return None
    idx = out[:m][::-1]
    cells = np.stack([idx // pw - 1, idx % pw - 1], axis=1)
    return GridPath(cells, float(total[0]), "compiled")


def _skimage_path(
    cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int], res: float
) -> GridPath | None:
    from skimage.graph import MCP_Geometric  # lazy: scikit-image only for this search

    grid = np.where(np.isfinite(cost), cost, -1.0)  # MCP: negative = impassable
    mcp = MCP_Geometric(grid, fully_connected=True)
    cum, _ = mcp.find_costs([tuple(start)], [tuple(goal)])
    total = cum[tuple(goal)]
    if not np.isfinite(total):
        return None
    cells = np.asarray(mcp.traceback(tuple(goal)), dtype=np.int64)
    return GridPath(cells, float(total) * res, "skimage")
