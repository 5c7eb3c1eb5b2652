"""Compiled search kernels for 8-connected cost grids (numba, compiled once and cached on disk).

Plain numpy cannot run a priority-queue search fast enough (a label-correcting row sweep needed
60-200 passes on terrain-like maps) and scikit-image's MCP is a generic Cython Dijkstra ~6x slower, so
two small kernels are compiled with numba (`njit(cache=True)`: the first call in a fresh environment
compiles for a few seconds, later processes load machine code from numba's cache; no C compiler is
needed at any time):

- `dial8`: exact Dijkstra on a bucket queue (Dial). The bucket width is at most the cheapest step, so
  no cell of the lowest bucket can improve another one in it: every cell of that bucket is final when
  it is reached, and a push is O(1). Each bucket is a growable int32 array.
- `astar8`: A* on a binary heap with the consistent heuristic `hmin x octile distance`, for grids where
  that bucket width would be 0 (zero-cost cells) or the cost range needs too many buckets.

Both take the cost grid padded with a border of +inf cells (no bounds checks in the inner loop), a
`closed` array in which impassable cells are already closed, and stop at the goal. They return the
number of path cells written to `out` (goal .. start, padded indices; 0 when the goal is unreachable)
and the path cost in `total[0]`. The caller (`search.plan_path`) validates every argument first: the
kernels do not check bounds.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["astar8", "dial8", "pad"]

_SQRT2 = np.sqrt(2.0)


@njit(cache=True, nogil=True, error_model="numpy")
def pad(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """One pass over a (h, w) cost grid: the flat grid with a border of +inf cells, `closed` (1 for every
    impassable or border cell), and the min and max finite cost and the most negative cost (0 if none)."""
    h, w = cost.shape
    pw = w + 2
    flat = np.full((h + 2) * pw, np.inf)
    closed = np.ones((h + 2) * pw, np.uint8)
    cmin = np.inf
    cmax = 0.0
    neg = 0.0
    for r in range(h):
        base = (r + 1) * pw + 1
        for c in range(w):
            x = cost[r, c]
            if np.isfinite(x):
                flat[base + c] = x
                closed[base + c] = 0
                if x < cmin:
                    cmin = x
                if x > cmax:
                    cmax = x
                if x < neg:
                    neg = x
    return flat, closed, cmin, cmax, neg


@njit(cache=True, nogil=True, error_model="numpy")
def _offsets(w: int, res: float) -> tuple[np.ndarray, np.ndarray]:
    off = np.array([-w - 1, -w, -w + 1, -1, 1, w - 1, w, w + 1], dtype=np.int64)
    d = res * _SQRT2
    step = np.array([d, res, d, res, res, d, res, d], dtype=np.float64)
    return off, step


@njit(cache=True, nogil=True, error_model="numpy")
def _trace(parent: np.ndarray, goal: int, out: np.ndarray) -> int:
    m = 0
    v = goal
    while v != -1:
        out[m] = v
        m += 1
        v = parent[v]
    return m


@njit(cache=True, nogil=True, error_model="numpy")
def dial8(
    cost: np.ndarray,
    w: int,
    res: float,
    start: int,
    goal: int,
    delta: float,
    nbuckets: int,
    closed: np.ndarray,
    out: np.ndarray,
    total: np.ndarray,
) -> int:
    """Exact Dijkstra with a bucket queue; `delta` <= the cheapest step, `nbuckets` > max step / delta + 1.
    `cost` flat (padded, row-major, width `w`); `closed` uint8, 1 for impassable and border cells."""
    n = cost.size
    off, step = _offsets(w, res)
    g = np.full(n, np.inf)
    parent = np.empty(n, np.int32)
    buckets = [np.empty(16, np.int32) for _ in range(nbuckets)]  # each bucket a growable array
    fill = np.zeros(nbuckets, np.int64)
    g[start] = 0.0
    parent[start] = -1
    buckets[0][0] = start
    fill[0] = 1
    pending = 1
    k = 0
    while pending > 0:
        b = k % nbuckets
        items = buckets[b]
        for j in range(fill[b]):
            u = items[j]
            if closed[u]:
                continue
            closed[u] = 1
            if u == goal:
                total[0] = g[goal]
                return _trace(parent, goal, out)
            gu = g[u]
            cu = cost[u]
            for q in range(8):
                v = u + off[q]
                if closed[v]:
                    continue
                nv = gu + step[q] * 0.5 * (cu + cost[v])
                if nv < g[v]:
                    g[v] = nv
                    parent[v] = u
                    kv = int(nv / delta)
                    if kv <= k:
                        kv = k + 1
                    t = kv % nbuckets
                    bt = buckets[t]
                    ft = fill[t]
                    if ft == bt.size:
                        grown = np.empty(2 * ft, np.int32)
                        grown[:ft] = bt
                        buckets[t] = grown
                        bt = grown
                    bt[ft] = v
                    fill[t] = ft + 1
                    pending += 1
        pending -= fill[b]
        fill[b] = 0
        k += 1
    return 0


@njit(cache=True, nogil=True, error_model="numpy")
def astar8(
    cost: np.ndarray,
    w: int,
    res: float,
    start: int,
    goal: int,
    hmin: float,
    closed: np.ndarray,
    out: np.ndarray,
    total: np.ndarray,
) -> int:
    """A* on a binary heap with the heuristic `hmin x octile distance` (hmin = 0: Dijkstra). Arguments
    as `dial8`; `hmin` a lower bound of every passable cell's cost."""
    n = cost.size
    off, step = _offsets(w, res)
    g = np.full(n, np.inf)
    parent = np.empty(n, np.int32)
    cap = 1 << 16
    hf = np.empty(cap, np.float64)
    hv = np.empty(cap, np.int64)
    size = 0
    gr = goal // w
    gc = goal % w
    hs = hmin * res
    hd = hmin * res * (_SQRT2 - 1.0)
    g[start] = 0.0
    parent[start] = -1
    hf[0] = 0.0
    hv[0] = start
    size = 1
    while size > 0:
        u = hv[0]
        # pop the root: sift the last item down
        size -= 1
        lf = hf[size]
        lv = hv[size]
        i = 0
        while True:
            c = 2 * i + 1
            if c >= size:
                break
            if c + 1 < size and hf[c + 1] < hf[c]:
                c += 1
            if lf <= hf[c]:
                break
            hf[i] = hf[c]
            hv[i] = hv[c]
            i = c
        if size > 0:
            hf[i] = lf
            hv[i] = lv
        if closed[u]:
            continue
        closed[u] = 1
        if u == goal:
            total[0] = g[goal]
            return _trace(parent, goal, out)
        gu = g[u]
        cu = cost[u]
        for q in range(8):
            v = u + off[q]
            if closed[v]:
                continue
            nv = gu + step[q] * 0.5 * (cu + cost[v])
            if nv < g[v]:
                g[v] = nv
                parent[v] = u
                h = 0.0
                if hmin > 0.0:
                    ar = abs(v // w - gr)
                    ac = abs(v % w - gc)
                    h = hs * ac + hd * ar if ar < ac else hs * ar + hd * ac
                f = nv + h
                if size == hf.size:
                    f2 = np.empty(2 * size, np.float64)
                    f2[:size] = hf
                    v2 = np.empty(2 * size, np.int64)
                    v2[:size] = hv
                    hf = f2
                    hv = v2
                i = size
                size += 1
                while i > 0:
                    p = (i - 1) >> 1
                    if hf[p] <= f:
                        break
                    hf[i] = hf[p]
                    hv[i] = hv[p]
                    i = p
                hf[i] = f
                hv[i] = v
    return 0
