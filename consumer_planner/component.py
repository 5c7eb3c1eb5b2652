"""The planner as a component: `plan(PlanConfig)` and `compare(CompareConfig)` -> `PlanSummary`.

Both fetch the map (from the map servers through `client`, or a saved `.npz`), build the cost grid
(`costs`), then search the cheapest path (`plan`) or break given routes down (`compare`), log them to
Rerun when asked, and return a typed summary whose `to_json()` is what `--json` prints. `psrmap plan` /
`psrmap compare` parse their options into these configs; the mission starts them in spawned processes.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from consumer_planner.client import ClientConfig, MapClient, RegionFollower
from consumer_planner.compare import Route, evaluate_route, plan_route
from consumer_planner.costs import CostConfig, CostMap, build_costs
from consumer_planner.errors import PlannerError
from psrmap_common.trust import load_trust
from psrmap_mapcore import LayerGrid, MapFileError, read_npz

__all__ = [
    "CompareConfig",
    "MapSource",
    "PlanConfig",
    "PlanSummary",
    "WatchSummary",
    "compare",
    "load_map",
    "plan",
    "plan_on",
    "watch_plan",
]

Point = tuple[float, float]


@dataclass(frozen=True)
class MapSource:
    """Where the map comes from: `npz` (a saved map) or map servers (`map_id` via `connect`), fetched
    with `margin_m` around the points; credentials and trusted server ids for a secured mission."""

    map_id: str | None = None
    connect: tuple[str, ...] = ()
    npz: str | None = None
    timeout_s: float = 5.0
    zenoh_config: str | None = None
    trust_servers: str | None = None  # servers.json; default: the one beside zenoh_config, if any
    margin_m: float = 10.0


@dataclass(frozen=True)
class PlanConfig:
    source: MapSource
    start: Point
    goal: Point
    cost: CostConfig = field(default_factory=CostConfig)
    goal_tolerance_m: float = 1.0
    rrd: str | None = None
    sim_time: float | None = None  # where the plan goes on the recording's sim_time (None: newest sample)


@dataclass(frozen=True)
class CompareConfig:
    source: MapSource
    routes: tuple[tuple[str, tuple[Point, ...]], ...]  # (name, points) of each route
    cost: CostConfig = field(default_factory=CostConfig)
    rrd: str | None = None
    sim_time: float | None = None


@dataclass(frozen=True)
class PlanSummary:
    map: str
    version: int
    cost: CostConfig
    routes: tuple[Route, ...]
    goal_moved_m: float | None = None  # plan: how far the goal moved to a passable cell
    grid_shape: tuple[int, int] = (0, 0)  # (h, w) cells fetched
    res: float = 0.0

    def head(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "map": self.map,
            "version": self.version,
            "unknown": self.cost.unknown,
            "slip_spread_m": self.cost.slip_spread_m,
            "weights": asdict(self.cost.weights),
        }
        if self.goal_moved_m is not None:
            out["goal_moved_m"] = self.goal_moved_m
        return out

    def to_json(self) -> dict[str, Any]:
        """plan: the head and the route's fields; compare: the head and `routes`."""
        if self.goal_moved_m is not None:
            return {**self.head(), **self.routes[0].as_dict()}
        return {**self.head(), "routes": [r.as_dict() for r in self.routes]}


def load_map(
    source: MapSource, points: list[Point], want_time: bool = False
) -> tuple[LayerGrid, float | None]:
    """The map around `points` and (want_time) the newest merged sample's time; PlannerError naming the
    problem when no map can be had."""
    if (source.npz is None) == (not source.connect):
        raise PlannerError("give either a map server endpoint (with a map id) or a saved map (.npz)")
    if source.npz is not None:
        try:
            return read_npz(source.npz, map_id=source.map_id or "local"), None
        except MapFileError as exc:
            raise PlannerError(str(exc)) from None
    if not source.map_id:
        raise PlannerError("a map server query needs the map id")

    with MapClient(_client_config(source)) as client:
        grid = client.region(source.map_id, _box(source, points))
        t = client.newest_sample_t(source.map_id) if want_time else None
    return grid, t


def _box(source: MapSource, points: list[Point]) -> tuple[float, float, float, float]:
    """The map area a query fetches: the points' bounding box and `margin_m` around it."""
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    m = source.margin_m
    return (min(xs) - m, min(ys) - m, max(xs) + m, max(ys) + m)


def _client_config(source: MapSource) -> ClientConfig:
    try:
        trust = load_trust(source.trust_servers, source.zenoh_config)
    except ValueError as exc:
        raise PlannerError(str(exc)) from None
    return ClientConfig(connect=source.connect, timeout_s=source.timeout_s, zenoh_config=source.zenoh_config,
                        trust=trust)  # fmt: skip


def _log(
    rrd: str | None, grid: LayerGrid, costs: CostMap, routes: list[Route], sim_time: float | None
) -> None:
    if rrd:
        from consumer_planner.viz import log_plan, open_recording  # lazy: Rerun only when recording

        rec = open_recording(rrd)
        log_plan(rec, grid, costs, routes, sim_time=sim_time or 0.0)
        rec.flush()


def plan(config: PlanConfig) -> PlanSummary:
    """The cheapest route from `start` to `goal`; PlannerError when there is none (or no map)."""
    if config.goal_tolerance_m < 0:
        raise PlannerError(f"goal tolerance {config.goal_tolerance_m}: need >= 0 metres")
    want_time = bool(config.rrd) and config.sim_time is None
    grid, t = load_map(config.source, [config.start, config.goal], want_time)
    return plan_on(grid, config, t)


def plan_on(grid: LayerGrid, config: PlanConfig, t: float | None = None) -> PlanSummary:
    """`plan` on a map already fetched (`t`: its newest sample time, where the recording logs the plan)."""
    costs = build_costs(grid, config.cost)
    route = plan_route(grid, costs, config.start, config.goal, goal_tolerance_m=config.goal_tolerance_m)
    if route is None:
        raise PlannerError(
            f"no passable route from {config.start} to {config.goal} "
            f"(unknown={config.cost.unknown}; try --unknown penalty or relax the limits)"
        )
    _log(config.rrd, grid, costs, [route], config.sim_time if config.sim_time is not None else t)
    end = route.path[-1]
    goal_cell = grid.cell_of(float(config.goal[0]), float(config.goal[1]))
    gx, gy = grid.centers(np.array([goal_cell]))[0] if goal_cell is not None else config.goal
    moved = round(math.hypot(end[0] - gx, end[1] - gy), 3)  # cell centre to cell centre
    return PlanSummary(grid.map, grid.version, costs.config, (route,), moved, grid.shape, grid.res)


@dataclass(frozen=True)
class WatchSummary:
    plans: int  # plans made (the first, then one per change of the corridor)
    failed: int  # replans that found no route (reported, the watch goes on)
    changes_in_box: int  # tile-change notices that touched the corridor
    resyncs: int  # replans forced by a status poll (a lost notice, or a server without notices)
    last: PlanSummary | None


def watch_plan(
    config: PlanConfig,
    on_plan: Callable[[PlanSummary | None, str | None, list[Any]], None],
    stop: threading.Event,
    resync_s: float = 10.0,
    period_s: float = 0.2,
    max_seconds: float | None = None,
) -> WatchSummary:
    """Plan, then replan each time the corridor (the map area `plan` fetches) changes: the shards' tile-change
    notices (`client.RegionFollower`), never on changes elsewhere on the map. `on_plan(summary, error, changes)`
    after every plan (error: why no route this time). Runs until `stop` is set or `max_seconds` passed."""
    source = config.source
    if source.npz is not None or not source.connect or not source.map_id:
        raise PlannerError("a watch follows map servers: give a map id and an endpoint, not a saved map")
    if config.goal_tolerance_m < 0:
        raise PlannerError(f"goal tolerance {config.goal_tolerance_m}: need >= 0 metres")
    box = _box(source, [config.start, config.goal])
    end = time.monotonic() + max_seconds if max_seconds else float("inf")
    plans = failed = 0
    last: PlanSummary | None = None
    with MapClient(_client_config(source)) as client:
        assert client.session is not None
        with RegionFollower(client.session, source.map_id, box, resync_s, source.timeout_s,
                            client.config.believed()) as follow:  # fmt: skip
            while not stop.is_set() and time.monotonic() < end:
                if follow.due():
                    changes = list(follow.last_changes)
                    statuses = follow.statuses()  # the plan reflects at least these versions
                    try:
                        grid = client.region(source.map_id, box)
                    except PlannerError as exc:  # servers gone: say so, try again next period
                        on_plan(None, str(exc), changes)
                        stop.wait(period_s)
                        continue
                    follow.done(statuses)
                    plans += 1
                    t = max((st.t for st in statuses), default=None) if config.rrd else None
                    try:
                        last = plan_on(grid, config, t)
                        on_plan(last, None, changes)
                    except PlannerError as exc:  # no route on this map: report, keep watching
                        failed += 1
                        on_plan(None, str(exc), changes)
                stop.wait(period_s)
            return WatchSummary(plans, failed, follow.changes_in_box, follow.resyncs, last)


def compare(config: CompareConfig) -> PlanSummary:
    """Each route's breakdown on the map; PlannerError when the map cannot be had or a route is invalid."""
    if not config.routes:
        raise PlannerError("no route to compare")
    want_time = bool(config.rrd) and config.sim_time is None
    grid, t = load_map(config.source, [p for _, pts in config.routes for p in pts], want_time)
    costs = build_costs(grid, config.cost)
    routes = [evaluate_route(grid, costs, list(pts), name=name) for name, pts in config.routes]
    _log(config.rrd, grid, costs, routes, config.sim_time if config.sim_time is not None else t)
    return PlanSummary(grid.map, grid.version, costs.config, tuple(routes), None, grid.shape, grid.res)
