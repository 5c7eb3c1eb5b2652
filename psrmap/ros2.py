"""`psrmap ros2`: the shared map on ROS 2, over ROS 2's own Zenoh middleware (rmw_zenoh).

Publishes, on a Zenoh network a ROS 2 system using `rmw_zenoh_cpp` shares (the same router):
- `<prefix>/grid_map`: `grid_map_msgs/msg/GridMap`, every layer's value (`<layer>`) and observation count
  (`<layer>_count`) over `--box`, by default over the whole map (the cells holding data, from the servers'
  status: the published grid grows with the map) (RViz's grid_map plugin, `ros2 topic echo`);
- `<prefix>/cost`: the planner's cost grid as `nav_msgs/msg/OccupancyGrid` (0..99 by cost, 100 impassable,
  -1 unknown);
- `<prefix>/plan`: with `--plan-from/--plan-to`, the planned path as `nav_msgs/msg/Path`;
all transient-local (a late subscriber gets the last one), at most `--rate` times a second and only when a tile
inside `--box` (without one: anywhere) changed (the servers' tile-change notices: a change elsewhere on the map
costs no query). Wire details in `psrmap_interop/rmw_zenoh.py`; messages in `psrmap_interop/ros2_messages.py`.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from dataclasses import dataclass
from typing import Any

from protocol.keys import id_arg
from psrmap_common.cli_parser import Subparsers
from psrmap_common.errors import QueryError, UsageError
from psrmap_common.link import add_link_arguments, link_from_args
from psrmap_common.session import zenoh_config

# Imports inside functions here are deliberate: `psrmap export` and `psrmap query --help` import this module
# and load no Zenoh, numpy or planner (tests/test_cli.py).

__all__ = ["TOPICS", "BridgeConfig", "box_arg", "register", "ros_keys", "run_bridge"]

# under the prefix; run_bridge declares their publishers in this order (entity ids 1, 2, 3)
TOPICS = ("grid_map", "cost", "plan")
NODE = "psrmap_bridge"


@dataclass(frozen=True)
class BridgeConfig:
    map_id: str
    box: tuple[float, float, float, float] | None  # None: the whole map (the extent in the servers' status)
    connect: tuple[str, ...]
    zenoh_config: str | None = None
    domain: int = 0
    prefix: str = "/psrmap"
    node: str = NODE
    frame: str = "map"
    rate_hz: float = 1.0
    plan_from: tuple[float, float] | None = None
    plan_to: tuple[float, float] | None = None
    once: bool = False  # publish the current map once, then exit
    max_seconds: float | None = None
    linger_s: float = 1.0  # with `once`: stay up this long so subscribers and caches get the samples
    # the bridge re-queries only when a tile inside its box changed (the shards' TileChanges notices,
    # consumer_planner.client.RegionWatch); every resync_s it also compares each server's version with the
    # notices it saw, and re-queries if one changed unannounced (a lost notice, or a server with changes off)
    resync_s: float = 10.0


def run_bridge(cfg: BridgeConfig, stop: threading.Event | None = None, log=print) -> dict[str, Any]:
    """Run until `stop` (or SIGTERM/SIGINT via the CLI), `once`, or `max_seconds`; returns what was published."""
    import zenoh

    from consumer_planner.client import ClientConfig, RegionFollower, query_region
    from consumer_planner.compare import plan_route
    from consumer_planner.costs import build_costs
    from consumer_planner.errors import PlannerError
    from psrmap_common.query import map_extent
    from psrmap_interop.rmw_zenoh import RosNode
    from psrmap_interop.ros2_messages import (
        GRID_MAP,
        OCCUPANCY_GRID,
        PATH,
        grid_map_msg,
        occupancy_grid_msg,
        path_msg,
    )

    stop = stop or threading.Event()
    conf = zenoh_config(cfg.connect, (), None if cfg.zenoh_config else "client", cfg.zenoh_config)
    conf.insert_json5("timestamping/enabled", "true")  # publication caches (transient local) need timestamps
    published = {"grid_map": 0, "cost": 0, "plan": 0}
    queries = 0
    counts: dict[str, int] = {}  # queries made, notices that touched the box, resyncs (status polls)
    t_end = time.monotonic() + cfg.max_seconds if cfg.max_seconds else float("inf")
    with zenoh.open(conf) as session:
        node = RosNode(session, cfg.node, domain=cfg.domain)
        # in TOPICS' order: the entity ids `ros_keys` grants (psrmap secure's bridge role)
        pubs = {"grid_map": node.publisher(f"{cfg.prefix}/grid_map", GRID_MAP),
                "cost": node.publisher(f"{cfg.prefix}/cost", OCCUPANCY_GRID)}  # fmt: skip
        if cfg.plan_from and cfg.plan_to:
            pubs["plan"] = node.publisher(f"{cfg.prefix}/plan", PATH)
        log(f"[ros2] node {cfg.node} on domain {cfg.domain}: " + ", ".join(p.topic for p in pubs.values()))
        last_version = None
        client = ClientConfig(connect=cfg.connect, zenoh_config=cfg.zenoh_config)
        follow = RegionFollower(session, cfg.map_id, cfg.box, cfg.resync_s, trusted=client.believed())
        last_error = ""
        try:
            while not stop.is_set() and time.monotonic() < t_end:
                grid = None
                if follow.due():
                    statuses = follow.statuses()  # the query reflects at least these versions
                    try:
                        box = cfg.box or map_extent(statuses, cfg.map_id)
                        grid = query_region(session, cfg.map_id, box, client)
                        queries += 1
                    except (
                        PlannerError,
                        QueryError,
                    ) as exc:  # servers gone or refusing, map empty: say so once
                        if str(exc) != last_error:
                            log(f"[ros2] map query failed: {exc}")
                        last_error = str(exc)
                if grid is not None:
                    last_error = ""
                    version = sum(st.version for st in statuses)
                    follow.done(statuses)
                    stamp = time.time_ns()
                    xa, ya, _, _ = grid.bounds_m()
                    layers = {}
                    for name in grid.layers:
                        layers[name] = grid.value(name)
                        layers[f"{name}_count"] = grid.count(name)
                    pubs["grid_map"].publish(grid_map_msg(layers, grid.res, xa, ya, cfg.frame, stamp), stamp)
                    costs = build_costs(grid)
                    pubs["cost"].publish(occupancy_grid_msg(costs.cost, costs.known, grid.res, xa, ya, cfg.frame,
                                                            stamp), stamp)  # fmt: skip
                    published["grid_map"] += 1
                    published["cost"] += 1
                    if "plan" in pubs:
                        try:
                            assert cfg.plan_from is not None and cfg.plan_to is not None
                            route = plan_route(grid, costs, cfg.plan_from, cfg.plan_to, goal_tolerance_m=1.0)
                        except PlannerError as exc:  # e.g. the start is off the map: keep serving the map
                            log(f"[ros2] no plan on v{version}: {exc}")
                            route = None
                        if route is not None:
                            pubs["plan"].publish(path_msg(route.path.tolist(), cfg.frame, stamp), stamp)
                            published["plan"] += 1
                    last_version = version
                    log(f"[ros2] map {cfg.map_id} v{version}: published {', '.join(pubs)}")
                if cfg.once and last_version is not None:
                    stop.wait(cfg.linger_s)
                    break
                stop.wait(1.0 / cfg.rate_hz)  # at most rate_hz maps a second; changes wait in the watch
        finally:
            counts = {"queries": queries, "changes_in_box": follow.changes_in_box, "resyncs": follow.resyncs}
            follow.close()
            node.close()
    return {"map": cfg.map_id, "version": last_version, "published": published, **counts,
            "topics": {k: p.key for k, p in pubs.items()}}  # fmt: skip


def ros_keys(domain: int = 0, prefix: str = "/psrmap", node: str = NODE) -> dict[str, list[str]]:
    """The keys a bridge on `domain` under `prefix` puts and declares (for the router's ACL, `psrmap.secure`):
    `<topic>` each topic's sample key, `<topic_token>` / `<node_token>` its publishers' and node's graph
    tokens (any session id), `<ros_graph>` the domain's whole graph."""
    from psrmap_interop.rmw_zenoh import Qos, node_token, publisher_token, topic_key
    from psrmap_interop.ros2_messages import GRID_MAP, OCCUPANCY_GRID, PATH

    topics = [
        (f"{prefix.rstrip('/')}/{t}", ty)
        for t, ty in zip(TOPICS, (GRID_MAP, OCCUPANCY_GRID, PATH), strict=True)
    ]
    return {
        "<topic>": [topic_key(domain, t, ty) for t, ty in topics],
        "<topic_token>": [
            publisher_token(domain, "*", 0, eid, "/", node, t, ty, Qos())
            for eid, (t, ty) in enumerate(topics, 1)
        ],  # fmt: skip
        "<node_token>": [node_token(domain, "*", 0, "/", node)],
        "<ros_graph>": [f"@ros2_lv/{domain}/**"],
    }


def _pair(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: need x,y in metres") from None
    return (x, y)


def box_arg(text: str) -> tuple[float, float, float, float]:
    """argparse type of `--box X0,Y0,X1,Y1` [m]: four numbers, x0 <= x1 and y0 <= y1."""
    try:
        x0, y0, x1, y1 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: need x0,y0,x1,y1 in map-frame metres") from None
    if x1 < x0 or y1 < y0:
        raise argparse.ArgumentTypeError(f"{text!r}: need x0 <= x1 and y0 <= y1")
    return (x0, y0, x1, y1)


def register(sub: Subparsers) -> None:
    p = sub.add_parser("ros2", help="publish the shared map, cost grid and plan to ROS 2 (rmw_zenoh)",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("--map", required=True, type=id_arg("map"), help="map id")
    add_link_arguments(p)
    p.add_argument("--box", type=box_arg, metavar="X0,Y0,X1,Y1",
                   help="map area to publish [m] (default: the whole map, as far as it holds data)")  # fmt: skip
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID (default 0)")
    p.add_argument("--prefix", default="/psrmap", help="topic namespace (default /psrmap)")
    p.add_argument("--frame", default="map", help="frame_id of every message (default map)")
    p.add_argument("--rate", type=float, default=1.0, help="at most this many updates per second (default 1)")
    p.add_argument("--plan-from", type=_pair, metavar="X,Y", help="also plan and publish a path from here…")
    p.add_argument("--plan-to", type=_pair, metavar="X,Y", help="…to here")
    p.add_argument(
        "--resync-s", type=float, default=10.0, metavar="S",
        help="every S seconds also check each server's map version, in case a tile-change notice was lost "
        "(default 10)",
    )  # fmt: skip
    p.add_argument("--once", action="store_true", help="publish the current map once and exit")
    p.add_argument("--max-seconds", type=float, help="stop after this long")
    p.set_defaults(func=_cmd)


def _cmd(args: argparse.Namespace) -> int:
    link = link_from_args(args)  # --connect, else the router --zenoh-config names
    if (args.plan_from is None) != (args.plan_to is None):
        raise UsageError("--plan-from and --plan-to go together")
    if args.rate <= 0:
        raise UsageError(f"--rate {args.rate}: need a positive number of updates per second")
    if not args.resync_s > 0:
        raise UsageError(f"--resync-s {args.resync_s}: need a period > 0 seconds")
    if not 0 <= args.domain <= 232:
        raise UsageError(f"--domain {args.domain}: ROS 2 domain ids are 0..232")
    if not args.prefix.startswith("/"):
        raise UsageError(f"--prefix {args.prefix!r}: a ROS namespace starts with '/'")
    cfg = BridgeConfig(args.map, args.box, link.connect, link.zenoh_config, args.domain,
                       args.prefix.rstrip("/"), frame=args.frame, rate_hz=args.rate, plan_from=args.plan_from,
                       plan_to=args.plan_to, once=args.once, max_seconds=args.max_seconds,
                       resync_s=args.resync_s)  # fmt: skip
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    print(json.dumps(run_bridge(cfg, stop)))
    return 0
