"""`psrmap router | server | remove` (also `python -m map_server ...`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

from map_server.errors import MapServerConfigError
from map_server.limits import Limits
from protocol.keys import id_arg
from psrmap_common.cli_parser import Parser, Subparsers, non_negative_int, positive_int, run_command
from psrmap_common.defaults import DEFAULT_RES_M
from psrmap_common.errors import UsageError
from psrmap_common.link import Link, add_link_arguments, link_from_args, open_link, split_endpoints
from psrmap_common.session import endpoint_arg, file_endpoints

if TYPE_CHECKING:
    from map_server.service import MapService, ServerConfig

# Imports inside functions here are deliberate: `psrmap router --help` loads no Zenoh or numpy
# (tests/test_cli.py).

__all__ = ["main", "register"]

log = logging.getLogger("map_server")


def _file_endpoints(args: argparse.Namespace, kind: str) -> tuple[str, ...]:
    """The endpoints of kind `connect`/`listen` named in `--zenoh-config`, or a usage error if unreadable."""
    try:
        return file_endpoints(getattr(args, "zenoh_config", None), kind)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _logging(args: argparse.Namespace) -> None:
    logging.basicConfig(
        level=logging.DEBUG if getattr(args, "verbose", False) else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
        stream=sys.stderr,
    )


def cmd_router(args: argparse.Namespace) -> int:
    _logging(args)
    listen = split_endpoints(args.listen)
    from map_server.component import stop_on_signals

    stop = stop_on_signals()
    link = Link(split_endpoints(args.connect), args.zenoh_config)
    with open_link(link, "router", listen, args.insecure):
        shown = listen or _file_endpoints(args, "listen")  # what it listens on, from the flags or the file
        print(json.dumps({"router": "up", "listen": list(shown)}), flush=True)
        stop.wait()
    return 0


def _bbox(text: str) -> tuple[float, float, float, float]:
    try:
        x0, y0, x1, y1 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give x0,y0,x1,y1 in map-frame metres") from None
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x0 > x1 or y0 > y1:
        raise argparse.ArgumentTypeError(f"{text!r}: need finite numbers with x0 <= x1 and y0 <= y1")
    return x0, y0, x1, y1


def server_config(args: argparse.Namespace) -> ServerConfig:
    """The parsed `psrmap server` options as a ServerConfig."""
    from map_server.service import ServerConfig

    return replace(
        ServerConfig(),
        map_id=args.map,
        res=args.res,
        db=args.db,
        tile=args.tile,
        connect=link_from_args(args, required=False).connect,
        listen=split_endpoints(args.listen),
        mode="router" if args.listen else "peer",
        rrd=args.rrd,
        zenoh_config=args.zenoh_config,
        insecure=args.insecure,
        shards=args.shards,
        shard=args.shard,
        tile_budget_mib=args.tile_budget_mib,
        bbox_m=args.bbox,
        keep_deltas=not args.discard_deltas,
        max_queries_in_flight=args.max_queries,
        linger_s=args.linger_ms / 1000.0,
        limits=Limits(**{f.name: getattr(args, f"limit_{f.name}") for f in dataclasses.fields(Limits)}),
    )


def cmd_server(args: argparse.Namespace) -> int:
    _logging(args)
    if not link_from_args(args, required=False).connect and not args.listen:
        raise UsageError(
            "give --connect tcp/HOST:PORT (a router) and/or --listen tcp/HOST:PORT, or a --zenoh-config file "
            "that names the router (psrmap secure init writes one)"
        )
    if not args.res > 0:
        raise UsageError(f"--res {args.res}: need a cell size > 0 [m]")
    if args.shards > 1 and (args.shard is None or not 0 <= args.shard < args.shards):
        raise UsageError(f"--shards {args.shards}: give --shard I with 0 ≤ I ≤ {args.shards - 1}")
    if args.tile_budget_mib is not None and (
        not args.tile_budget_mib >= 0 or (args.tile_budget_mib and not args.db)
    ):
        raise UsageError(
            f"--tile-budget-mib {args.tile_budget_mib}: need a budget >= 0 MiB (0: none) and, above 0, --db PATH"
        )
    if not 0 <= args.linger_ms <= 100:
        raise UsageError(f"--linger-ms {args.linger_ms}: need 0 (no wait) to 100 ms")
    if args.shards == 1 and args.shard not in (None, 0):
        raise UsageError(f"--shard {args.shard}: a sharded map needs --shards K > 1 as well")
    cfg = server_config(args)

    def up(service: MapService) -> None:
        print(json.dumps({"server": "up", "map": cfg.map_id, "cells": service.cells,
                          "replayed": service.replayed}), flush=True)  # fmt: skip

    from map_server.component import run as run_server

    try:
        summary = run_server(cfg, on_up=up)
    except MapServerConfigError as exc:
        raise UsageError(str(exc)) from None
    return summary.exit_code


def cmd_remove(args: argparse.Namespace) -> int:
    """Remove one scout's (or epoch's) contributions from a stopped server's database, exactly."""
    from map_server.removal import RemovalError, remove_contributions

    if args.scout is None and args.epoch is None:
        raise UsageError("give --scout ID and/or --epoch E: whose contributions to remove")
    try:
        summary = remove_contributions(args.db, args.scout, args.epoch)
    except RemovalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(summary.to_json(), indent=2))
    return 0


def register(subparsers: Subparsers) -> None:
    """Add `router`, `server`, `remove` to the `psrmap` CLI."""
    p = subparsers.add_parser("router", help="run an embedded Zenoh router")
    p.add_argument(
        "--listen", type=endpoint_arg, action="append", default=None, help="endpoint, e.g. tcp/127.0.0.1:7447"
    )
    add_link_arguments(p, listens=True)
    p.set_defaults(func=cmd_router)

    p = subparsers.add_parser("server", help="run the map server of one map")
    p.add_argument("--map", required=True, type=id_arg("map"), help="map id ([A-Za-z0-9_-]+)")
    p.add_argument(
        "--res", type=float, default=DEFAULT_RES_M, help=f"cell size [m] (default {DEFAULT_RES_M})"
    )
    p.add_argument("--db", default=None, help="SQLite file (default: memory only, nothing persisted)")
    p.add_argument("--tile", type=int, default=64, help="tile side [cells], a power of two")
    p.add_argument(
        "--listen",
        type=endpoint_arg,
        action="append",
        default=None,
        help="also run as a router listening here",
    )
    p.add_argument("--rrd", default=None, help="log merged layers to this Rerun .rrd file")
    p.add_argument(
        "--shards", type=positive_int, default=1, metavar="K",
        help="the map is split over K shard servers by tile (protocol.partition; default 1: unsharded)",
    )  # fmt: skip
    p.add_argument(
        "--shard", type=int, default=None, metavar="I", help="with --shards K: this server's shard, 0..K-1"
    )
    p.add_argument(
        "--tile-budget-mib",
        type=float,
        default=None,
        metavar="MIB",
        help="keep at most this many MiB of tiles in memory, the rest in the --db file (a map bigger than "
        "memory); default: 1/16 of physical memory within 64..256 MiB (without --db it caps the map's tiles); "
        "0: no budget",
    )
    p.add_argument(
        "--bbox",
        type=_bbox,
        default=None,
        metavar="X0,Y0,X1,Y1",
        help="mission area [m], map frame: deltas with a cell outside are rejected (outside_bbox); negative "
        "numbers: --bbox=-10,-10,10,10",
    )
    p.add_argument(
        "--discard-deltas",
        action="store_true",
        help="delete logged deltas once a snapshot covers them (less disk; `psrmap remove` is then impossible)",
    )
    p.add_argument(
        "--max-queries",
        type=positive_int,
        default=64,
        metavar="N",
        help="queries queued or being answered at most; more get a `busy` reply (deltas never wait on queries)",
    )
    p.add_argument(
        "--linger-ms",
        type=float,
        default=2.0,
        metavar="MS",
        help="when few deltas are queued, wait this long once for more before merging (larger commits; default 2)",
    )
    add_link_arguments(p, listens=True)
    g = p.add_argument_group("limits (a message or query over one is rejected, naming it)")
    for f in dataclasses.fields(Limits):
        g.add_argument(
            f"--limit-{f.name.replace('_', '-')}",
            dest=f"limit_{f.name}",
            type=positive_int,
            default=f.default,
            metavar="N",
            help=f"(default {f.default})",
        )
    p.add_argument("-v", "--verbose", action="store_true")
    p.set_defaults(func=cmd_server)

    p = subparsers.add_parser(
        "remove",
        help="remove one scout's (or epoch's) contributions from a stopped server's --db, exactly",
        description="Recompute every tile the removed deltas touched from the remaining ones (min/max included) "
        "and record the removal in the database's `removals` table. The server must be stopped (it holds "
        "DB.lock); a sharded map: run it on each shard's database.",
    )
    p.add_argument("--db", required=True, help="the map server's SQLite file")
    p.add_argument("--scout", type=id_arg("scout"), default=None, help="the scout whose deltas to remove")
    p.add_argument(
        "--epoch",
        type=non_negative_int,
        default=None,
        help="only this epoch (without --scout: of every scout)",
    )
    p.set_defaults(func=cmd_remove)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m map_server")
    register(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    return run_command(parser, argv)
