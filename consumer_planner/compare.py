"""Routes on the map with their breakdown: planned ones (`plan_route`) and given ones (`evaluate_route`).

Every figure is a sum over the route's cells p_0 .. p_k with the weight w_j = half the length [m] of
the steps entering and leaving p_j (`cell_weights`), the same weighting that defines the path cost in
`search` (step a -> b costs len * (cost[a] + cost[b]) / 2), so:

- length_m = sum w_j; cost = sum w_j cost_j (equals the search's path cost); terms[t] = sum w_j term_t,j
  (they add up to `cost`);
- expected_slip_events = stances_per_m * sum w_j slip_rate_j (cells without a rate count 0);
- mean_cot, mean_giim, mean_giam = w-weighted means over cells with a value (known or inferred);
- min_giim, min_giam = the smallest cell mean on the route; max_slope_deg = the largest cell slope;
- unknown_fraction = share of length on cells without data; inferred_fraction = share on inferred cells.

Means, minima and maxima with no cell to take them from are NaN (JSON null).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from skimage.draw import line

from consumer_planner.costs import CostMap
from consumer_planner.errors import PlannerError
from protocol.layers import LAYERS, layer_derived
from psrmap_common.pathsearch import Method, PathSearchError, nearest_passable, plan_path, step_lengths
from psrmap_mapcore import LayerGrid

__all__ = ["Breakdown", "Route", "blocked_message", "breakdown", "cell_weights", "evaluate_route", "plan_route",
           "route_cells", "why_impassable"]  # fmt: skip


@dataclass(frozen=True)
class Breakdown:
    length_m: float
    cost: float
    expected_slip_events: float
    mean_cot: float
    min_giim: float
    mean_giim: float
    min_giam: float
    mean_giam: float
    max_slope_deg: float
    mean_placement_sigma_m: float  # how well the path's cells are placed: the scouts' horizontal σ [m]
    max_placement_sigma_m: float
    mean_height_sigma_m: float  # how well the path's heights are known: the scouts' vertical σ [m]
    max_height_sigma_m: float
    unknown_fraction: float
    inferred_fraction: float
    impassable_cells: int
    terms: dict[str, float]

    def as_dict(self) -> dict:
        """JSON-ready: NaN and inf become None."""
        return _jsonable(asdict(self))


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


@dataclass(frozen=True, eq=False)
class Route:
    """A route: `cells` (k, 2) (row, col), `path` (k, 2) map-frame cell centres [m], its breakdown."""

    name: str
    cells: np.ndarray
    path: np.ndarray
    breakdown: Breakdown

    def as_dict(self) -> dict:
        b = self.breakdown.as_dict()
        return {"name": self.name, "path": self.path.round(4).tolist(), "length_m": b["length_m"],
                "cost": b["cost"], "breakdown": b}  # fmt: skip


def cell_weights(cells: np.ndarray, res: float) -> np.ndarray:
    """(k,) half the length [m] of the steps entering and leaving each cell of a path (k, 2)."""
    steps = step_lengths(cells, res)
    w = np.zeros(len(cells))
    w[:-1] += 0.5 * steps
    w[1:] += 0.5 * steps
    return w


def _wmean(w: np.ndarray, v: np.ndarray) -> float:
    ok = np.isfinite(v)
    return float(np.sum(w[ok] * v[ok]) / np.sum(w[ok])) if ok.any() and np.sum(w[ok]) > 0 else math.nan


def _extreme(fn, v: np.ndarray) -> float:
    ok = np.isfinite(v)
    return float(fn(v[ok])) if ok.any() else math.nan


def breakdown(
    costs: CostMap,
    cells: np.ndarray,
    res: float,
    placement: np.ndarray | None = None,
    height_sigma: np.ndarray | None = None,
) -> Breakdown:
    """The figures above for a path of 8-connected cells (k, 2) on `costs`; `placement` (h, w): the map's
    placement σ per cell [m] (`protocol.layers` "placement"), `height_sigma` (h, w): its vertical σ per cell
    [m] (the "height" layer's `sigma`), both read only for the breakdown."""
    cells = np.asarray(cells, dtype=np.int64)
    r, c = cells[:, 0], cells[:, 1]
    w = cell_weights(cells, res)
    length = float(w.sum())
    m = {k: v[r, c] for k, v in costs.metrics.items()}
    place = placement[r, c] if placement is not None else np.full(len(r), np.nan)
    vert = height_sigma[r, c] if height_sigma is not None else np.full(len(r), np.nan)
    blocked = costs.impassable[r, c]
    cost = math.inf if blocked.any() else float(np.sum(w * costs.cost[r, c]))
    frac = (lambda mask: float(np.sum(w[mask]) / length)) if length > 0 else (lambda mask: 0.0)
    return Breakdown(
        length_m=length,
        cost=cost,
        expected_slip_events=float(costs.config.stances_per_m * np.sum(w * np.nan_to_num(m["slip_rate"]))),
        mean_cot=_wmean(w, m["cot"]),
        min_giim=_extreme(np.min, m["giim"]),
        mean_giim=_wmean(w, m["giim"]),
        min_giam=_extreme(np.min, m["giam"]),
        mean_giam=_wmean(w, m["giam"]),
        max_slope_deg=_extreme(np.max, m["slope_deg"]),
        mean_placement_sigma_m=_wmean(w, place),
        max_placement_sigma_m=_extreme(np.max, place),
        mean_height_sigma_m=_wmean(w, vert),
        max_height_sigma_m=_extreme(np.max, vert),
        unknown_fraction=frac(~costs.known[r, c]),
        inferred_fraction=frac(costs.inferred[r, c]),
        impassable_cells=int(blocked.sum()),
        terms={k: float(np.sum(w * v[r, c])) for k, v in costs.terms.items()},
    )


def _sigmas(grid: LayerGrid) -> tuple[np.ndarray, np.ndarray | None]:
    """The map's placement σ and vertical σ per cell [m] (None without the height layer's raw stats)."""
    stats = grid.layers.get("height")
    if stats is None or not all(s in stats for s in LAYERS["height"].stats):
        return grid.value("placement"), None
    return grid.value("placement"), layer_derived("height", "sigma", stats)


def _cell(grid: LayerGrid, xy: Sequence[float], what: str) -> tuple[int, int]:
    cell = grid.cell_of(float(xy[0]), float(xy[1]))
    if cell is None:
        xa, ya, xb, yb = grid.bounds_m()
        raise PlannerError(
            f"{what} ({xy[0]:g}, {xy[1]:g}) is outside the map box x {xa:g}..{xb:g}, y {ya:g}..{yb:g} m"
        )
    return cell


SUGGEST_RADIUS_M = 5.0  # a blocked endpoint's message names the nearest passable cell within this distance


def why_impassable(costs: CostMap, cell: tuple[int, int]) -> str:
    """Why the cell (row, col) is impassable, in the words of `costs`' rules ("" when it is passable)."""
    if np.isfinite(costs.cost[cell]):
        return ""
    m = {k: float(v[cell]) for k, v in costs.metrics.items()}
    lim, cfg = costs.config.limits, costs.config
    reasons = [
        f"{text} ({value:.3g} {op} limit {limit:g})"
        for text, value, op, limit, over in (
            ("slope", m["slope_deg"], ">", lim.max_slope_deg, m["slope_deg"] > lim.max_slope_deg),
            ("GIIM", m["giim"], "<", lim.min_giim_rad, m["giim"] < lim.min_giim_rad),
            ("GIAM", m["giam"], "<", lim.min_giam, m["giam"] < lim.min_giam),
            ("slip rate", m["slip_rate"], ">", lim.max_slip_rate, m["slip_rate"] > lim.max_slip_rate),
        )
        if over
    ]
    if not costs.known[cell] and not costs.inferred[cell] and not reasons:
        reasons.append(f"no map data (unknown policy {cfg.unknown!r})")
    if not reasons and cfg.hazard == "forbid":
        reasons.append(f"a scout's hazard report within {cfg.hazard_spread_m:g} m (hazard policy 'forbid')")
    return "; ".join(reasons) or "impassable"


def blocked_message(
    grid: LayerGrid, costs: CostMap, what: str, cell: tuple[int, int], xy: Sequence[float]
) -> str:
    """The planner's error for an impassable start or goal: why, and the nearest cell that would be valid."""
    near = nearest_passable(costs.cost, cell, SUGGEST_RADIUS_M / grid.res)
    if near is None:
        valid = f"no passable cell within {SUGGEST_RADIUS_M:g} m"
    else:
        x, y = grid.centers(np.array([near]))[0]
        valid = f"nearest passable cell: ({x:.2f}, {y:.2f}) m, {math.dist(near, cell) * grid.res:.2f} m away"
    return (
        f"{what} ({xy[0]:g}, {xy[1]:g}) m, cell (row {cell[0]}, col {cell[1]}), is impassable: "
        f"{why_impassable(costs, cell)}; {valid}"
    )


def route_cells(grid: LayerGrid, waypoints: Sequence[Sequence[float]]) -> np.ndarray:
    """The 8-connected cells (k, 2) visited by straight segments between map-frame waypoints [m]."""
    if len(waypoints) < 1:
        raise PlannerError("a route needs at least one waypoint x,y")
    ends = [_cell(grid, p, f"waypoint {i}") for i, p in enumerate(waypoints)]
    cells = [np.array([ends[0]])]
    for (r0, c0), (r1, c1) in zip(ends[:-1], ends[1:], strict=True):
        rr, cc = line(r0, c0, r1, c1)
        cells.append(np.stack([rr, cc], axis=1)[1:])
    return np.concatenate(cells).astype(np.int64)


def evaluate_route(
    grid: LayerGrid, costs: CostMap, waypoints: Sequence[Sequence[float]], name: str = "route"
) -> Route:
    """A given route (map-frame waypoints [m]) on the map, with its breakdown."""
    cells = route_cells(grid, waypoints)
    return Route(name, cells, grid.centers(cells), breakdown(costs, cells, grid.res, *_sigmas(grid)))


def plan_route(
    grid: LayerGrid,
    costs: CostMap,
    start: Sequence[float],
    goal: Sequence[float],
    name: str = "plan",
    method: Method = "auto",
    goal_tolerance_m: float = 0.0,
) -> Route | None:
    """The cheapest route from `start` to `goal` (map-frame [m]); None if the goal cannot be reached. With
    `goal_tolerance_m`, a goal on an impassable cell is moved to the nearest passable cell within that distance
    (the route then ends there: compare its last point with `goal`)."""
    s, g = _cell(grid, start, "start"), _cell(grid, goal, "goal")
    if goal_tolerance_m > 0:
        g = nearest_passable(costs.cost, g, goal_tolerance_m / grid.res) or g
    for what, cell, xy in (("start", s, start), ("goal", g, goal)):
        if not np.isfinite(costs.cost[cell]):
            raise PlannerError(blocked_message(grid, costs, what, cell, xy))
    try:
        found = plan_path(costs.cost, s, g, grid.res, method)
    except PathSearchError as exc:
        raise PlannerError(str(exc)) from None
    if found is None:
        return None
    b = breakdown(costs, found.cells, grid.res, *_sigmas(grid))
    return Route(name, found.cells, grid.centers(found.cells), b)
