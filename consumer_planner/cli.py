"""`psrmap plan` and `psrmap compare`: costed paths and route breakdowns from the shared (or a saved) map.

    psrmap plan --map ID --connect tcp/HOST:7447 --from x,y --to x,y [--weights cot=1,slip=2]
                [--unknown forbid|penalty|infer] [--slip-spread M] [--hazard forbid|penalty] [--json] [--rrd PATH]
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
import signal
import threading
from dataclasses import asdict, replace

from consumer_planner import component
from consumer_planner.compare import Route
from consumer_planner.component import CompareConfig, MapSource, PlanConfig, PlanSummary
from consumer_planner.cost_config import HAZARD_POLICIES
from consumer_planner.costs import TERMS, UNKNOWN_POLICIES, CostConfig, parse_weights
from consumer_planner.errors import PlannerError
from consumer_planner.table import route_table, term_lines
from protocol.keys import id_arg
from psrmap_common.cli_parser import Subparsers, positive_float
from psrmap_common.errors import UsageError
from psrmap_common.link import add_link_arguments, link_from_args

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
    add_link_arguments(src)
    src.add_argument(
        "--npz", metavar="FILE", help="a saved map (.npz, map_region layout) instead of a server"
    )
    src.add_argument(
        "--timeout", type=positive_float, default=5.0, help="seconds to wait for map servers (default 5)"
    )
    src.add_argument(
        "--trust-servers",
        metavar="FILE",
        help="servers.json from `psrmap secure init`: accept replies and tile-change notices only from the "
        "attested map servers (default: the servers.json beside --zenoh-config, if there is one)",
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
    p.add_argument(
        "--hazard",
        choices=HAZARD_POLICIES,
        default=CostConfig.hazard,
        help="cells near a scout's hazard report: forbid (impassable, default) or penalty",
    )
    p.add_argument(
        "--hazard-penalty",
        type=float,
        default=CostConfig.hazard_penalty,
        metavar="C",
        help=f"with --hazard penalty: added cost [1/m] (default {CostConfig.hazard_penalty:g})",
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


def register(subparsers: Subparsers) -> None:
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
    w = p.add_argument_group("following the map (with --connect)")
    w.add_argument(
        "--watch",
        action="store_true",
        help="keep planning: replan each time a tile of the corridor changes (the servers' tile-change "
        "notices; changes elsewhere on the map cost nothing); one line or JSON object per plan",
    )
    w.add_argument(
        "--resync-s", type=float, default=10.0, metavar="S",
        help="with --watch: also check the servers' versions every S seconds, in case a notice was lost (default 10)",
    )  # fmt: skip
    w.add_argument(
        "--max-seconds", type=float, default=None, metavar="S", help="with --watch: stop after S s"
    )
    p.set_defaults(func=_run_plan)
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
    c.set_defaults(func=_run_compare)


def _config(args: argparse.Namespace) -> CostConfig:
    if args.unknown not in UNKNOWN_POLICIES:
        raise UsageError(f"--unknown {args.unknown!r}; choose one of: {', '.join(UNKNOWN_POLICIES)}")
    try:
        return replace(
            CostConfig(),
            weights=parse_weights(args.weights),
            unknown=args.unknown,
            slip_spread_m=args.slip_spread,
            hazard=args.hazard,
            hazard_penalty=args.hazard_penalty,
        )
    except PlannerError as exc:
        raise UsageError(f"--weights/--hazard-penalty: {exc}") from None


def _source(args: argparse.Namespace) -> MapSource:
    link = link_from_args(args, required=False)
    if (args.npz is None) == (not link.connect):
        raise UsageError("give either --connect ENDPOINT (with --map ID) or --npz FILE")
    if link.connect and not args.map:
        raise UsageError("--connect needs --map ID")
    return MapSource(map_id=args.map, connect=link.connect, npz=args.npz, timeout_s=args.timeout,
                     zenoh_config=link.zenoh_config, trust_servers=args.trust_servers, margin_m=args.margin)  # fmt: skip


def _table(routes: list[Route]) -> str:
    rows = [{"name": r.name, "breakdown": asdict(r.breakdown)} for r in routes]
    return "\n".join([route_table(rows), "", *term_lines(rows)])


def _print(args: argparse.Namespace, summary: PlanSummary) -> int:
    if args.json:
        print(json.dumps(summary.to_json()))
    else:
        h, w = summary.grid_shape
        print(
            f"map {summary.map} v{summary.version}, {w}x{h} cells of {summary.res:g} m, "
            f"unknown={summary.cost.unknown}, slip spread {summary.cost.slip_spread_m:g} m"
        )
        print(_table(list(summary.routes)))
    return 0


def _run_plan(args: argparse.Namespace) -> int:
    if args.goal_tolerance < 0:
        raise UsageError(f"--goal-tolerance {args.goal_tolerance}: need >= 0 metres")
    cfg = PlanConfig(_source(args), args.start, args.goal, _config(args), args.goal_tolerance, args.rrd,
                     args.sim_time)  # fmt: skip
    if args.watch:
        return _watch(args, cfg)
    try:
        return _print(args, component.plan(cfg))
    except PlannerError as exc:
        raise SystemExit(f"psrmap plan: {exc}") from None


def _watch(args: argparse.Namespace, cfg: PlanConfig) -> int:
    if args.npz is not None:
        raise UsageError("--watch follows map servers: give --connect and --map, not --npz")
    if not args.resync_s > 0:
        raise UsageError(f"--resync-s {args.resync_s}: need a period > 0 seconds")
    if args.max_seconds is not None and not args.max_seconds > 0:
        raise UsageError(f"--max-seconds {args.max_seconds}: need a duration > 0 seconds")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    def on_plan(summary: PlanSummary | None, error: str | None, changes: list) -> None:
        tiles = sorted({(int(x), int(y)) for c in changes for x, y in c.tiles.tolist()})
        why = {"changed_tiles": tiles, "versions": {str(c.shard): c.version for c in changes}}
        if args.json:
            out = summary.to_json() if summary is not None else {"error": error}
            print(json.dumps({**out, **why}), flush=True)
        elif summary is None:
            print(f"no plan: {error}", flush=True)
        else:
            r = summary.routes[0]
            cause = f"{len(tiles)} tile(s) of the corridor changed" if tiles else "first plan / resync"
            print(f"map {summary.map} v{summary.version}: {r.breakdown.length_m:.1f} m, cost {r.breakdown.cost:.2f} "
                  f"({cause})", flush=True)  # fmt: skip

    try:
        res = component.watch_plan(cfg, on_plan, stop, args.resync_s, max_seconds=args.max_seconds)
    except PlannerError as exc:
        raise SystemExit(f"psrmap plan --watch: {exc}") from None
    print(json.dumps({"watch": {"plans": res.plans, "failed": res.failed, "changes_in_box": res.changes_in_box,
                                "resyncs": res.resyncs}}))  # fmt: skip
    return 0


def _run_compare(args: argparse.Namespace) -> int:
    if len(args.name) > len(args.route):
        raise UsageError(
            f"{len(args.name)} --name for {len(args.route)} --route: give at most one name per route"
        )
    names = [*args.name, *(f"route{i}" for i in range(len(args.name), len(args.route)))]
    routes = tuple((name, tuple(pts)) for name, pts in zip(names, args.route, strict=True))
    cfg = CompareConfig(_source(args), routes, _config(args), args.rrd, args.sim_time)
    try:
        return _print(args, component.compare(cfg))
    except PlannerError as exc:
        raise SystemExit(f"psrmap compare: {exc}") from None
