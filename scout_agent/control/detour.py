"""Going around: a path to the goal on what the scout knows, avoiding the ground it could not hold.

A cost grid of `res` cells over the field (`bounds`, the mission area) costs 1 per metre everywhere; cells
within `hazard_radius_m` of a hazard the scout felt (its own reports, each with its own radius when given as
(x, y, r), and any in a known map's `hazard` layer) are impassable; cells of a known map whose slip rate is above `slip_rate_avoid` cost
`slip_penalty` more per metre. The search is the planner's own (`psrmap_common.pathsearch.plan_path`, exact
8-connected Dijkstra). The cell path becomes waypoints by keeping only the cells where a straight walk to
the next kept one would cross a dearer or forbidden cell (line of sight on the grid).

If the scout stands inside a hazard's radius (it backed off to the last place it held, which may be close),
that hazard's radius shrinks to just short of the scout for this plan: it may walk out, never further in.
A goal inside a hazard radius moves to the nearest free cell within `goal_tolerance_m`. None when no path
exists.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from skimage.draw import line

from psrmap_common.pathsearch import nearest_passable, plan_path
from psrmap_mapcore import LayerGrid

__all__ = ["DetourConfig", "plan_detour"]


@dataclass(frozen=True)
class DetourConfig:
    res: float = 0.2  # grid cell [m]
    hazard_radius_m: float = 1.2  # keep at least this far from a hazard report (a patch is ≈ 1.6 m wide)
    edge_margin_m: float = 0.6  # stay this far inside the field's edge
    slip_rate_avoid: float = 0.25  # known cells slipping more often than this cost extra
    slip_penalty: float = 4.0  # [1/m]
    goal_tolerance_m: float = 1.0


def _grid(bounds: tuple[float, float, float, float], res: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    xa, ya, xb, yb = bounds
    xs = np.arange(xa + res / 2, xb, res)
    ys = np.arange(ya + res / 2, yb, res)
    X, Y = np.meshgrid(xs, ys)
    return np.ones(X.shape), X, Y


def plan_detour(
    start: Sequence[float] | np.ndarray,
    goal: Sequence[float] | np.ndarray,
    hazards: Sequence[Sequence[float]],
    bounds: tuple[float, float, float, float],
    config: DetourConfig = DetourConfig(),
    known: LayerGrid | None = None,
) -> np.ndarray | None:
    """Waypoints (k, 2) [m, map frame] from `start` to `goal` around `hazards` [(x, y) or (x, y, radius)],
    or None."""
    c = config
    xa, ya, xb, yb = bounds
    inner = (xa + c.edge_margin_m, ya + c.edge_margin_m, xb - c.edge_margin_m, yb - c.edge_margin_m)
    cost, X, Y = _grid(bounds, c.res)
    cost[(X < inner[0]) | (X > inner[2]) | (Y < inner[1]) | (Y > inner[3])] = np.inf
    pts = [(float(h[0]), float(h[1]), float(h[2]) if len(h) > 2 else c.hazard_radius_m) for h in hazards]
    if known is not None:
        pts += [(x, y, c.hazard_radius_m) for x, y in _known_hazards(known)]
        _add_slip(cost, X, Y, known, c)
    sx, sy = float(start[0]), float(start[1])
    for hx, hy, hr in pts:
        r = min(hr, math.hypot(sx - hx, sy - hy) - c.res)
        cost[(X - hx) ** 2 + (Y - hy) ** 2 < r * r] = np.inf
    rc = lambda x, y: (  # noqa: E731
        int(np.clip((y - ya) // c.res, 0, cost.shape[0] - 1)),
        int(np.clip((x - xa) // c.res, 0, cost.shape[1] - 1)),
    )
    s = rc(sx, sy)
    cost[s] = 1.0
    g = nearest_passable(cost, rc(float(goal[0]), float(goal[1])), c.goal_tolerance_m / c.res)
    if g is None:
        return None
    found = plan_path(cost, s, g, c.res)
    if found is None:
        return None
    keep = _line_of_sight(cost, found.cells)
    way = np.stack([X[keep[:, 0], keep[:, 1]], Y[keep[:, 0], keep[:, 1]]], axis=1)
    way[0] = (sx, sy)
    return way


def _known_hazards(known: LayerGrid) -> list[tuple[float, float]]:
    if "hazard" not in known.layers:
        return []
    v = known.value("hazard")
    rows, cols = np.nonzero(np.isfinite(v) & (v > 0))
    if not len(rows):
        return []
    centres = known.centers(np.stack([rows, cols], axis=1))
    return [(float(x), float(y)) for x, y in centres]


def _add_slip(cost: np.ndarray, X: np.ndarray, Y: np.ndarray, known: LayerGrid, c: DetourConfig) -> None:
    if "slip" not in known.layers:
        return
    rate = known.value("slip")
    rows, cols = np.nonzero(np.isfinite(rate) & (rate > c.slip_rate_avoid))
    if not len(rows):
        return
    half = known.res / 2
    for x, y in known.centers(np.stack([rows, cols], axis=1)):
        cost[(np.abs(X - x) <= half) & (np.abs(Y - y) <= half)] += c.slip_penalty


def _line_of_sight(cost: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The cells of a path worth keeping as waypoints: greedily, the farthest cell reachable in a straight
    line over cells no dearer than the cheapest the path itself crossed there."""
    keep = [0]
    i, n = 0, len(cells)
    while i < n - 1:
        j = n - 1
        while j > i + 1:
            rr, cc = line(int(cells[i][0]), int(cells[i][1]), int(cells[j][0]), int(cells[j][1]))
            seg = cost[rr, cc]
            if np.all(np.isfinite(seg)) and seg.max() <= cost[cells[i : j + 1, 0], cells[i : j + 1, 1]].max():
                break
            j -= 1
        keep.append(j)
        i = j
    return cells[keep]
