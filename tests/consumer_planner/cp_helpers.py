"""Constructed maps and an independent reference Dijkstra for the consumer_planner tests."""

from __future__ import annotations

import heapq
import math

import numpy as np

from psrmap_mapcore import LayerGrid


def make_grid(shape, res=0.5, *, ix0=0, iy0=0, known=None, cot=1.0, slip=0.0, giim=0.6, giam=0.9, n=20.0):
    """A LayerGrid with uniform (or per-cell array) layers; `known` (h, w) bool selects cells with data."""
    h, w = shape
    known = np.ones(shape, bool) if known is None else np.asarray(known, bool)
    nn = np.where(known, n, 0.0)

    def full(v):
        return np.where(known, np.broadcast_to(np.asarray(v, float), shape), np.nan)

    layers = {
        "cot": {"value": full(cot), "n": nn},
        "slip": {"value": full(slip), "n": nn},
        "giim": {"value": full(giim), "n": nn},
        "giam": {"value": full(giam), "n": nn},
    }
    return LayerGrid("test", res, ix0, iy0, h, w, layers)


def reference_dijkstra(cost, start, goal, res):
    """Textbook heapq Dijkstra on the 8-connected graph, step cost len * (c_a + c_b) / 2."""
    h, w = cost.shape
    dist = {start: 0.0}
    prev = {}
    heap = [(0.0, start)]
    done = set()
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        done.add(u)
        if u == goal:
            break
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == dc == 0:
                    continue
                v = (u[0] + dr, u[1] + dc)
                if not (0 <= v[0] < h and 0 <= v[1] < w) or not math.isfinite(cost[v]):
                    continue
                step = res * (math.sqrt(2) if dr and dc else 1.0) * 0.5 * (cost[u] + cost[v])
                if d + step < dist.get(v, math.inf):
                    dist[v] = d + step
                    prev[v] = u
                    heapq.heappush(heap, (d + step, v))
    if goal not in done:
        return None, None
    path = [goal]
    while path[-1] != start:
        path.append(prev[path[-1]])
    return dist[goal], path[::-1]


def path_cost(cost, cells, res):
    """Sum of step costs along a cell path, one step at a time."""
    total = 0.0
    for a, b in zip(cells[:-1], cells[1:], strict=True):
        a, b = tuple(a), tuple(b)
        assert max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1, "path must be 8-connected"
        diag = a[0] != b[0] and a[1] != b[1]
        total += res * (math.sqrt(2) if diag else 1.0) * 0.5 * (cost[a] + cost[b])
    return total
