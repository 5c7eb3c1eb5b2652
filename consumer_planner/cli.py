"""`psrmap plan` and `psrmap compare`: costed paths and route breakdowns from the shared (or a saved) map.

    psrmap plan --map ID --connect tcp/HOST:7447 --from x,y --to x,y [--weights cot=1,slip=2]
                [--unknown forbid|penalty|infer] [--slip-spread M] [--json] [--rrd PATH]
    psrmap compare --map ID --connect ... --route "x,y x,y ..." [--route ...] [--json]

`--npz FILE` plans on a scout's saved map instead of querying a server. `--slip-spread M` (default
0.8 m, 0 = the raw slip layer): each cell's slip term reads the largest slip rate within M metres
(`consumer_planner.costs`). Output: a table, or with `--json` one JSON object (`plan`: path, length_m,
cost, breakdown; `compare`: routes = a list of those).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from consumer_planner.compare import Route, evaluate_route, plan_route
from consumer_planner.costs import TERMS, UNKNOWN_POLICIES, CostConfig, build_costs, parse_weights
from consumer_planner.errors import PlannerError
from consumer_planner.table import route_table, term_lines
from mapcore import LayerGrid, MapFileError, read_npz
from protocol.keys import id_arg

__all__ = ["register"]

Point = tuple[float, float]


def _point(text: str) -> Point:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a point; give x,y in map-frame metres") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"{text!r}: coordinates must be finite")
    return x, y


def _route(text: str) -> list[Point]:
    pts = [_point(p) for p in text.split()]
    if not pts:
        raise argparse.ArgumentTypeError('a route is "x,y x,y ..." with at least one point')
    return pts


def _spread(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v >= 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(
            f"{text!r}: give a radius in metres, 0 <= M < inf (0 = the raw slip layer)"
        )
    return v


def _common(p: argparse.ArgumentParser) -> None:
    src = p.add_argument_group("map source (one of --connect, --npz)")
    src.add_argument("--map", metavar="ID", type=id_arg("map"), help="map id (with --connect)")
    src.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        default=[],
        help="Zenoh endpoint of a router or map server, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    src.add_argument(
        "--npz", metavar="FILE", help="a saved map (.npz, map_region layout) instead of a server"
    )
    src.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for map servers (default 5)")
    src.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh config with this planner's credentials (`psrmap secure init`)",
    )
    src.add_argument(
        "--trust-servers",
        metavar="FILE",
        help="servers.json from `psrmap secure init`: accept map replies only from those server ids "
        "(default: the servers.json beside --zenoh-config, if there is one)",
    )
    src.add_argument(
        "--margin", type=float, default=10.0, help="metres of map fetched around the points (default 10)"
    )
    p.add_argument(
        "--weights", default="", metavar="NAME=W,...", help=f"term weights; names: {', '.join(TERMS)}"
    )
    p.add_argument(
        "--unknown",
        default="penalty",
        metavar="POLICY",
        help=f"unknown cells: {' | '.join(UNKNOWN_POLICIES)} (default penalty)",
    )
    p.add_argument(
        "--slip-spread",
        type=_spread,
        default=CostConfig.slip_spread_m,
        metavar="M",
        help="each cell's slip term reads the largest slip rate within M metres, 0 <= M "
        f"(default {CostConfig.slip_spread_m:g}; 0 = the raw slip layer)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--rrd", metavar="PATH", help="also save a Rerun recording of the cost grid and routes")
    p.add_argument(
        "--sim-time",
        type=float,
        metavar="S",
        help="log the plan at S seconds on the recording's sim_time (mission time; default: the newest "
        "sample the map servers merged, or 0 for --npz)",
    )


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plan",
        help="cheapest path on the shared map, with its breakdown",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(p)
    p.add_argument(
        "--from",
        dest="start",
        type=_point,
        required=True,
        metavar="X,Y",
        help="start [m]; write --from=-1,2 when x is negative",
    )
    p.add_argument("--to", dest="goal", type=_point, required=True, metavar="X,Y")
    p.add_argument(
        "--goal-tolerance",
        type=float,
        default=1.0,
        metavar="M",
        help="a goal on an impassable cell moves to the nearest passable cell within M metres "
        "(default 1; 0: fail instead)",
    )
    p.set_defaults(func=_run_plan, _parser=p)
    c = subparsers.add_parser(
        "compare",
        help="breakdowns of given routes on the shared map",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(c)
    c.add_argument("--route", type=_route, action="append", required=True, metavar='"X,Y X,Y ..."')
    c.add_argument(
        "--name",
        action="append",
        default=[],
        metavar="NAME",
        help="name of each --route, in order (default route0, route1, ...)",
    )
    c.set_defaults(func=_run_compare, _parser=c)


def _config(args: argparse.Namespace) -> CostConfig:
    if args.unknown not in UNKNOWN_POLICIES:
        args._parser.error(f"--unknown {args.unknown!r}; choose one of: {', '.join(UNKNOWN_POLICIES)}")
    try:
        return replace(
            CostConfig(),
            weights=parse_weights(args.weights),
            unknown=args.unknown,
            slip_spread_m=args.slip_spread,
        )
    except PlannerError as exc:
        args._parser.error(f"--weights: {exc}")
        raise  # unreachable: error() exits


def _load(args: argparse.Namespace, points: list[Point]) -> LayerGrid:
    if (args.npz is None) == (not args.connect):
        args._parser.error("give either --connect ENDPOINT (with --map ID) or --npz FILE")
    if args.npz is not None:
        try:
            return read_npz(args.npz, map_id=args.map or "local")
        except MapFileError as exc:
            raise PlannerError(str(exc)) from None
    if not args.map:
        args._parser.error("--connect needs --map ID")
    from consumer_planner.client import ClientConfig, MapClient  # zenoh only when a server is asked

    xs, ys = [p[0] for p in points], [p[1] for p in points]
    m = args.margin
    box = (min(xs) - m, min(ys) - m, max(xs) + m, max(ys) + m)
    from consumer_planner.client import trusted_servers

    trust = args.trust_servers or (
        str(Path(args.zenoh_config).with_name("servers.json")) if args.zenoh_config else None
    )
    try:
        ids = trusted_servers(trust, required=bool(args.trust_servers))
    except ValueError as exc:
        args._parser.error(str(exc))
    cfg = ClientConfig(
        connect=tuple(args.connect),
        timeout_s=args.timeout,
        zenoh_config=args.zenoh_config,
        trusted_servers=ids,
    )
    with MapClient(cfg) as client:
        grid = client.region(args.map, box)
        if args.rrd and args.sim_time is None:
            args.sim_time = client.newest_sample_t(args.map)
        return grid


def _table(routes: list[Route]) -> str:
    rows = [{"name": r.name, "breakdown": asdict(r.breakdown)} for r in routes]
    return "\n".join([route_table(rows), "", *term_lines(rows)])


def _finish(args: argparse.Namespace, grid: LayerGrid, costs, routes: list[Route], single: bool) -> int:
    if args.rrd:
        from consumer_planner.viz import log_plan, open_recording

        rec = open_recording(args.rrd)
        log_plan(rec, grid, costs, routes, sim_time=args.sim_time or 0.0)
        rec.flush()
    head = {
        "map": grid.map,
        "version": grid.version,
        "unknown": costs.config.unknown,
        "slip_spread_m": costs.config.slip_spread_m,
        "weights": asdict(costs.config.weights),
    }
    if single and getattr(args, "goal", None) is not None:
        end = routes[0].path[-1]
        goal_cell = grid.cell_of(float(args.goal[0]), float(args.goal[1]))
        gx, gy = grid.centers(np.array([goal_cell]))[0] if goal_cell is not None else args.goal
        head["goal_moved_m"] = round(math.hypot(end[0] - gx, end[1] - gy), 3)  # cell centre to cell centre
    if args.json:
        body = routes[0].as_dict() if single else {"routes": [r.as_dict() for r in routes]}
        print(json.dumps({**head, **body}))
    else:
        size = f"{grid.w}x{grid.h} cells of {grid.res:g} m"
        print(
            f"map {grid.map} v{grid.version}, {size}, unknown={head['unknown']}, "
            f"slip spread {head['slip_spread_m']:g} m"
        )
        print(_table(routes))
    return 0


def _run_plan(args: argparse.Namespace) -> int:
    cfg = _config(args)
    try:
        grid = _load(args, [args.start, args.goal])
        costs = build_costs(grid, cfg)
        if args.goal_tolerance < 0:
            args._parser.error(f"--goal-tolerance {args.goal_tolerance}: need >= 0 metres")
        route = plan_route(grid, costs, args.start, args.goal, goal_tolerance_m=args.goal_tolerance)
    except PlannerError as exc:
        raise SystemExit(f"psrmap plan: {exc}") from None
    if route is None:
        raise SystemExit(
            f"psrmap plan: no passable route from {args.start} to {args.goal} "
            f"(unknown={cfg.unknown}; try --unknown penalty or relax the limits)"
        )
    return _finish(args, grid, costs, [route], single=True)


def _run_compare(args: argparse.Namespace) -> int:
    cfg = _config(args)
    if len(args.name) > len(args.route):
        args._parser.error(
            f"{len(args.name)} --name for {len(args.route)} --route: give at most one name per route"
        )
    names = [*args.name, *(f"route{i}" for i in range(len(args.name), len(args.route)))]
    try:
        grid = _load(args, [p for r in args.route for p in r])
        costs = build_costs(grid, cfg)
        routes = [
            evaluate_route(grid, costs, pts, name=name) for name, pts in zip(names, args.route, strict=True)
        ]
    except PlannerError as exc:
        raise SystemExit(f"psrmap compare: {exc}") from None
    return _finish(args, grid, costs, routes, single=False)
