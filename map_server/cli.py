"""`psrmap router | server | status | query` (also `python -m map_server ...`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from common.cli_parser import Parser, non_negative_int, positive_float, positive_int
from common.defaults import DEFAULT_RES_M
from common.session import endpoint_arg
from map_server.limits import Limits
from protocol.errors import MAX_CLIENT_CELLS
from protocol.keys import id_arg

__all__ = ["main", "register"]

log = logging.getLogger("map_server")


def add_security_arguments(p: argparse.ArgumentParser, listens: bool = False) -> None:
    """`--zenoh-config FILE` (credentials, TLS: `psrmap secure init`) and, for what listens, `--insecure`."""
    p.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh config with this agent's credentials (`psrmap secure init` writes one per agent)",
    )
    if listens:
        p.add_argument(
            "--insecure",
            action="store_true",
            help="allow listening on a non-loopback endpoint without credentials",
        )


def _conf(
    args: argparse.Namespace, connect: Sequence[str] = (), listen: Sequence[str] = (), mode: str = "client"
) -> Any:
    """The Zenoh config of a command, or a usage error naming what would have been valid."""
    from common.session import zenoh_config

    file = getattr(args, "zenoh_config", None)
    try:
        return zenoh_config(connect, listen, None if file else mode, file, getattr(args, "insecure", False))
    except ValueError as exc:
        args.parser.error(str(exc))


def _endpoints(values: Sequence[str] | None) -> tuple[str, ...]:
    out: list[str] = []
    for v in values or ():
        out.extend(e for e in v.split(",") if e)
    return tuple(out)


def _file_endpoints(args: argparse.Namespace, kind: str) -> tuple[str, ...]:
    """The endpoints of kind `connect`/`listen` named in `--zenoh-config`, or a usage error if unreadable."""
    from common.session import file_endpoints

    try:
        return file_endpoints(getattr(args, "zenoh_config", None), kind)
    except ValueError as exc:
        args.parser.error(str(exc))
        raise  # unreachable: error() exits


def _client_endpoints(args: argparse.Namespace) -> tuple[str, ...]:
    """`--connect`, else the router the `--zenoh-config` file names, else a usage error."""
    eps = _endpoints(args.connect) or _file_endpoints(args, "connect")
    if not eps:
        args.parser.error("give --connect tcp/HOST:PORT (a router), or a --zenoh-config file that names one")
    return eps


def _logging(args: argparse.Namespace) -> None:
    logging.basicConfig(
        level=logging.DEBUG if getattr(args, "verbose", False) else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
        stream=sys.stderr,
    )


def _open(conf: Any, args: argparse.Namespace) -> Any:
    """A Zenoh session, or a usage error that names the endpoints and what would have worked."""
    from common.session import SessionError, open_session

    try:
        return open_session(conf)
    except SessionError as exc:  # it names the endpoints: nothing listens there, or credentials are needed
        args.parser.error(str(exc))


def cmd_router(args: argparse.Namespace) -> int:
    _logging(args)
    listen = _endpoints(args.listen)
    from map_server.component import stop_on_signals

    stop = stop_on_signals()
    with _open(_conf(args, _endpoints(args.connect), listen, "router"), args):
        shown = listen or _file_endpoints(args, "listen")  # what it listens on, from the flags or the file
        print(json.dumps({"router": "up", "listen": list(shown)}), flush=True)
        stop.wait()
    return 0


def _bbox(text: str) -> tuple[float, float, float, float]:
    import math

    try:
        x0, y0, x1, y1 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give x0,y0,x1,y1 in map-frame metres") from None
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x0 > x1 or y0 > y1:
        raise argparse.ArgumentTypeError(f"{text!r}: need finite numbers with x0 <= x1 and y0 <= y1")
    return x0, y0, x1, y1


def server_config(args: argparse.Namespace) -> Any:
    """The parsed `psrmap server` options as a ServerConfig."""
    from map_server.service import ServerConfig

    return replace(
        ServerConfig(),
        map_id=args.map,
        res=args.res,
        db=args.db,
        tile=args.tile,
        connect=_endpoints(args.connect),
        listen=_endpoints(args.listen),
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
    from map_server import component
    from map_server.errors import MapServerConfigError

    _logging(args)
    if not args.connect and not args.listen:
        args.connect = list(_file_endpoints(args, "connect"))
    if not args.connect and not args.listen:
        args.parser.error(
            "give --connect tcp/HOST:PORT (a router) and/or --listen tcp/HOST:PORT, or a --zenoh-config file "
            "that names the router (psrmap secure init writes one)"
        )
    if not args.res > 0:
        args.parser.error(f"--res {args.res}: need a cell size > 0 [m]")
    if args.shards > 1 and (args.shard is None or not 0 <= args.shard < args.shards):
        args.parser.error(f"--shards {args.shards}: give --shard I with 0 ≤ I ≤ {args.shards - 1}")
    if args.tile_budget_mib is not None and (
        not args.tile_budget_mib >= 0 or (args.tile_budget_mib and not args.db)
    ):
        args.parser.error(
            f"--tile-budget-mib {args.tile_budget_mib}: need a budget >= 0 MiB (0: none) and, above 0, --db PATH"
        )
    if not 0 <= args.linger_ms <= 100:
        args.parser.error(f"--linger-ms {args.linger_ms}: need 0 (no wait) to 100 ms")
    if args.shards == 1 and args.shard not in (None, 0):
        args.parser.error(f"--shard {args.shard}: a sharded map needs --shards K > 1 as well")
    cfg = server_config(args)

    def up(service: Any) -> None:
        print(json.dumps({"server": "up", "map": cfg.map_id, "cells": service.cells,
                          "replayed": service.replayed}), flush=True)  # fmt: skip

    try:
        summary = component.run(cfg, on_up=up)
    except MapServerConfigError as exc:
        args.parser.error(str(exc))
    return summary.exit_code


def _trust(args: argparse.Namespace) -> Any:
    """Whose replies to believe (common.trust): the servers.json beside --zenoh-config, if there is one."""
    from common.trust import load_trust

    try:
        return load_trust(None, getattr(args, "zenoh_config", None))
    except ValueError as exc:
        args.parser.error(str(exc))


def _get_all(args: argparse.Namespace, selector: str) -> list[bytes]:
    """Every server's (every shard's) good reply (`common.query`, fanned out), or exit 1 saying why none."""
    from common.query import get_replies

    trust = _trust(args)
    with _open(_conf(args, _client_endpoints(args)), args) as s:
        replies = get_replies(s, selector, args.timeout, fan_out=True, trusted=trust)
    if replies.ok:
        return replies.ok
    why = "; ".join(replies.errors) or f"no reply within {args.timeout:g} s (is a server for this map up?)"
    print(f"error: {selector!r}: {why}", file=sys.stderr)
    raise SystemExit(1)


def cmd_status(args: argparse.Namespace) -> int:
    """The map's status; for a sharded map the aggregate over its shards, each shard's own under `shards`."""
    from common.query import aggregate_status, get_statuses

    trust = _trust(args)
    with _open(_conf(args, _client_endpoints(args)), args) as s:
        parts = get_statuses(s, args.map, args.timeout, trust)
    if not parts:
        print(f"error: no server of map {args.map!r} answered within {args.timeout:g} s", file=sys.stderr)
        return 1
    out = aggregate_status(parts).to_json()
    if parts[0].shards > 1:
        out["shard_status"] = [p.to_json() for p in sorted(parts, key=lambda p: p.shard or 0)]
    print(json.dumps(out, indent=2))
    return 0


QUERY_FORMATS = ("npz", "geotiff", "mcap")


def _format_of(out: str | None) -> str:
    low = (out or "").lower()
    return "geotiff" if low.endswith((".tif", ".tiff")) else "mcap" if low.endswith(".mcap") else "npz"


def _write_interop(args: argparse.Namespace, region: Any, fmt: str) -> str:
    """The region as a GeoTIFF or a rosbag2/MCAP (interop), from its `value` and `n` stats."""
    import math
    from pathlib import Path

    missing = [n for n, st in region.layers.items() if "value" not in st or "n" not in st]
    if missing:
        args.parser.error(
            f"--format {fmt} needs the value and n stats of every layer (--stats value,n); "
            f"missing for {', '.join(missing)}"
        )
    values = {n: st["value"] for n, st in region.layers.items()}
    counts = {n: st["n"] for n, st in region.layers.items()}
    x0, y0 = region.ix0 * region.res, region.iy0 * region.res
    if fmt == "geotiff":
        from interop.geotiff import MoonOrigin, write_geotiff

        try:
            origin = MoonOrigin.parse(args.origin) if args.origin else None
        except ValueError as exc:
            args.parser.error(str(exc))
        return str(write_geotiff(args.out, values, counts, region.res, x0, y0, origin,
                                 tags={"PSRMAP_MAP": region.map, "PSRMAP_VERSION": str(region.version)}))  # fmt: skip
    from interop.ros2_messages import GRID_MAP, grid_map_msg
    from interop.rosbag import BagMessage, write_mcap_bag

    out = Path(args.out)
    if out.exists():
        args.parser.error(f"--out {out}: exists; a rosbag2 is written into a new folder")
    layers = {**values, **{f"{n}_count": c for n, c in counts.items()}}
    stamp = math.floor(time.time() * 1e9)
    msg = grid_map_msg(layers, region.res, x0, y0, "map", stamp)
    return str(write_mcap_bag(out, [BagMessage("/psrmap/grid_map", GRID_MAP, msg, stamp)]))


def cmd_query(args: argparse.Namespace) -> int:
    import numpy as np

    from protocol.codec import decode
    from protocol.keys import map_key
    from protocol.messages import MapRegion, RegionQuery

    if args.box is None:  # the whole map: the cells holding data, from every server's (shard's) status
        from common.errors import QueryError
        from common.query import get_statuses, map_extent

        trust = _trust(args)
        with _open(_conf(args, _endpoints(args.connect)), args) as s:
            try:
                x0, y0, x1, y1 = map_extent(get_statuses(s, args.map, args.timeout, trust), args.map)
            except QueryError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 1
    else:
        try:
            x0, y0, x1, y1 = (float(v) for v in args.box.split(","))
        except ValueError:
            args.parser.error(f"--box {args.box!r}: give x0,y0,x1,y1 in map-frame metres")
    layers = tuple(args.layers.split(",")) if args.layers else None
    rq = RegionQuery(x0, y0, x1, y1, layers, tuple(args.stats.split(",")))
    from mapcore import MapCoreError, check_replies, stitch
    from protocol.errors import ProtocolError

    regions = []
    try:
        for payload in _get_all(args, f"{map_key(args.map)}?{rq.to_parameters()}"):
            r = decode(payload, expected_type="map_region", max_bytes=args.max_reply_mib << 20)
            assert isinstance(r, MapRegion)
            regions.append(r)
        # each reply's box and the union's size checked before anything is allocated for them
        check_replies(regions, (x0, y0, x1, y1), args.max_cells)
        region = regions[0]
        if len(regions) > 1:  # a sharded map: each shard answers for the tiles it owns
            g = stitch(regions, box_m=(x0, y0, x1, y1), max_cells=args.max_cells)
            region = MapRegion(
                g.map, g.res, g.ix0, g.iy0, g.w, g.h, sum(r.version for r in regions), g.layers
            )
    except (ProtocolError, MapCoreError) as exc:
        print(f"error: map {args.map!r}: bad reply: {exc}", file=sys.stderr)
        return 1
    summary: dict[str, Any] = {
        "map": region.map,
        "res": region.res,
        "ix0": region.ix0,
        "iy0": region.iy0,
        "w": region.w,
        "h": region.h,
        "version": region.version,
        "layers": {},
    }
    for name, stats in region.layers.items():
        n = stats.get("n")
        known = int(np.count_nonzero(n > 0)) if n is not None else None
        entry: dict[str, Any] = {"cells_with_data": known}
        if "value" in stats and np.isfinite(stats["value"]).any():
            v = stats["value"][np.isfinite(stats["value"])]
            entry.update(value_min=float(v.min()), value_mean=float(v.mean()), value_max=float(v.max()))
        summary["layers"][name] = entry
    fmt = args.format or _format_of(args.out)
    if args.out and fmt != "npz":
        summary["out"] = _write_interop(args, region, fmt)
        summary["format"] = fmt
    elif args.out:  # the map core's one .npz layout (<layer>/<stat> arrays; mapcore.read_npz reads it)
        from mapcore import LayerGrid, write_npz

        write_npz(args.out, LayerGrid.from_region(region))
        summary["out"] = args.out
    print(json.dumps(summary, indent=2))
    return 0


def cmd_remove(args: argparse.Namespace) -> int:
    """Remove one scout's (or epoch's) contributions from a stopped server's database, exactly."""
    from map_server.removal import RemovalError, remove_contributions

    if args.scout is None and args.epoch is None:
        args.parser.error("give --scout ID and/or --epoch E: whose contributions to remove")
    try:
        summary = remove_contributions(args.db, args.scout, args.epoch)
    except RemovalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(summary.to_json(), indent=2))
    return 0


def register(subparsers: Any) -> None:
    """Add `router`, `server`, `remove`, `status`, `query` to the `psrmap` CLI."""
    p = subparsers.add_parser("router", help="run an embedded Zenoh router")
    p.add_argument(
        "--listen", type=endpoint_arg, action="append", default=None, help="endpoint, e.g. tcp/127.0.0.1:7447"
    )
    p.add_argument(
        "--connect", type=endpoint_arg, action="append", default=None, help="other routers to mesh with"
    )
    add_security_arguments(p, listens=True)
    p.set_defaults(func=cmd_router, parser=p)

    p = subparsers.add_parser("server", help="run the map server of one map")
    p.add_argument("--map", required=True, type=id_arg("map"), help="map id ([A-Za-z0-9_-]+)")
    p.add_argument(
        "--res", type=float, default=DEFAULT_RES_M, help=f"cell size [m] (default {DEFAULT_RES_M})"
    )
    p.add_argument("--db", default=None, help="SQLite file (default: memory only, nothing persisted)")
    p.add_argument("--tile", type=int, default=64, help="tile side [cells], a power of two")
    p.add_argument(
        "--connect",
        type=endpoint_arg,
        action="append",
        default=None,
        help="router endpoint, e.g. tcp/127.0.0.1:7447",
    )
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
    add_security_arguments(p, listens=True)
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
    p.set_defaults(func=cmd_server, parser=p)

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
    p.set_defaults(func=cmd_remove, parser=p)

    for name, fn, helptext in (
        ("status", cmd_status, "print a map server's status"),
        ("query", cmd_query, "query a box of the map"),
    ):
        p = subparsers.add_parser(name, help=helptext)
        p.add_argument("--map", required=True, type=id_arg("map"), help="map id ([A-Za-z0-9_-]+)")
        p.add_argument(
            "--connect",
            type=endpoint_arg,
            action="append",
            help="router endpoint (default: the one the --zenoh-config file names)",
        )
        p.add_argument("--timeout", type=positive_float, default=5.0, help="reply timeout [s]")
        add_security_arguments(p)
        if name == "query":
            p.add_argument(
                "--box", help="x0,y0,x1,y1 [m], inclusive (default: the whole map, as far as it holds data)"
            )
            p.add_argument(
                "--max-cells",
                type=positive_int,
                default=MAX_CLIENT_CELLS,
                metavar="N",
                help=f"refuse replies spanning more cells than this (default {MAX_CLIENT_CELLS})",
            )
            p.add_argument(
                "--max-reply-mib",
                type=positive_int,
                default=64,
                metavar="MIB",
                help="refuse a reply larger than this (default 64, the server's max_reply_bytes)",
            )
            p.add_argument("--layers", default=None, help="comma-separated layers (default: all)")
            p.add_argument("--stats", default="value,n", help="stats, derived names, or 'all'")
            p.add_argument(
                "--out",
                default=None,
                help="write the region to this file: .npz (arrays), .tif (GeoTIFF), or a new folder for "
                "--format mcap (rosbag2)",
            )
            p.add_argument(
                "--format",
                choices=QUERY_FORMATS,
                help="format of --out (default from its extension: .tif/.tiff geotiff, .mcap mcap, else npz)",
            )
            p.add_argument(
                "--origin",
                metavar="LAT,LON[,HEADING]",
                help="geotiff: the map origin on the Moon [deg]; the file is then in IAU_2015:30135",
            )
        p.set_defaults(func=fn, parser=p)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m map_server")
    register(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)
