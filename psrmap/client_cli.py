"""`psrmap status | query`: the map service's client commands, asking through `psrmap_common.query`.

`status` prints a map's status (for a sharded map the aggregate over its shards, each shard's own under
`shard_status`); `query` fetches a box of the map (by default the whole map, as far as it holds data), prints
what each layer holds and, with `--out`, writes it through `psrmap.export.write_export`, the one writer of
the map's file formats (`psrmap export` writes through it too).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from protocol.errors import MAX_CLIENT_CELLS
from protocol.keys import id_arg
from psrmap.export import add_out_arguments, format_of, origin_from_args, write_export
from psrmap_common.cli_parser import Subparsers, positive_float, positive_int
from psrmap_common.errors import QueryError, UsageError
from psrmap_common.link import Link, add_link_arguments, link_from_args, open_link

if TYPE_CHECKING:
    from psrmap_common.trust import Trust
    from psrmap_mapcore import LayerGrid

# Imports inside functions here are deliberate: `psrmap status/query --help` load no Zenoh or numpy
# (tests/test_cli.py).

__all__ = ["cmd_query", "cmd_status", "register"]


def _trust(link: Link) -> Trust:
    """Whose replies to believe (psrmap_common.trust): the servers.json beside --zenoh-config, if there is one."""
    from psrmap_common.trust import load_trust

    try:
        return load_trust(None, link.zenoh_config)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def cmd_status(args: argparse.Namespace) -> int:
    """The map's status; for a sharded map the aggregate over its shards, each shard's own under `shards`."""
    from psrmap_common.query import aggregate_status, get_statuses

    link = link_from_args(args)
    trust = _trust(link)
    with open_link(link) as s:
        parts = get_statuses(s, args.map, args.timeout, trust)
    if not parts:
        print(f"error: no server of map {args.map!r} answered within {args.timeout:g} s", file=sys.stderr)
        return 1
    out = aggregate_status(parts).to_json()
    if parts[0].shards > 1:
        out["shard_status"] = [p.to_json() for p in sorted(parts, key=lambda p: p.shard or 0)]
    print(json.dumps(out, indent=2))
    return 0


def _box(args: argparse.Namespace, link: Link, trust: Trust) -> tuple[float, float, float, float] | None:
    """`--box`, else the whole map as far as it holds data (every server's status); None (said why) if none."""
    if args.box is not None:
        try:
            x0, y0, x1, y1 = (float(v) for v in args.box.split(","))
        except ValueError:
            raise UsageError(f"--box {args.box!r}: give x0,y0,x1,y1 in map-frame metres") from None
        return x0, y0, x1, y1
    from psrmap_common.query import get_statuses, map_extent

    with open_link(link) as s:
        try:
            return map_extent(get_statuses(s, args.map, args.timeout, trust), args.map)
        except QueryError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return None


def _region(
    args: argparse.Namespace, link: Link, trust: Trust, box: tuple[float, float, float, float]
) -> LayerGrid | None:
    """The box from every server (shard) that answers, stitched (`psrmap_common.region.fetch_region`, as the planner
    and the bridge fetch it: each reply's size and box checked before anything is allocated); None (said why)
    when there is none or a reply is bad."""
    from psrmap_common.region import NoAnswer, fetch_region

    layers = tuple(args.layers.split(",")) if args.layers else None
    with open_link(link) as s:
        try:
            return fetch_region(s, args.map, box, args.timeout, trusted=trust, layers=layers,
                                stats=tuple(args.stats.split(",")), max_bytes=args.max_reply_mib << 20,
                                max_cells=args.max_cells)  # fmt: skip
        except NoAnswer:
            why = f"no reply within {args.timeout:g} s (is a server for this map up?)"
        except QueryError as exc:
            why = str(exc)
    print(f"error: map {args.map!r}: {why}", file=sys.stderr)
    return None


def _layer_summary(stats: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    n = stats.get("n")
    entry: dict[str, Any] = {"cells_with_data": int(np.count_nonzero(n > 0)) if n is not None else None}
    if "value" in stats and np.isfinite(stats["value"]).any():
        v = stats["value"][np.isfinite(stats["value"])]
        entry.update(value_min=float(v.min()), value_mean=float(v.mean()), value_max=float(v.max()))
    return entry


def cmd_query(args: argparse.Namespace) -> int:
    link = link_from_args(args)
    origin = origin_from_args(args)  # a bad --origin is found before any query
    trust = _trust(link)
    box = _box(args, link, trust)
    region = None if box is None else _region(args, link, trust, box)
    if region is None:
        return 1
    summary: dict[str, Any] = {
        "map": region.map,
        "res": region.res,
        "ix0": region.ix0,
        "iy0": region.iy0,
        "w": region.w,
        "h": region.h,
        "version": region.version,
        "layers": {name: _layer_summary(stats) for name, stats in region.layers.items()},
    }
    if args.out:
        fmt = format_of(args.out, args.format)
        summary["out"] = str(write_export(region, args.out, fmt, origin))
        summary["format"] = fmt
    print(json.dumps(summary, indent=2))
    return 0


def register(subparsers: Subparsers) -> None:
    """Add `status` and `query` to the `psrmap` CLI."""
    for name, fn, helptext in (
        ("status", cmd_status, "print a map server's status"),
        ("query", cmd_query, "query a box of the map"),
    ):
        p = subparsers.add_parser(name, help=helptext)
        p.add_argument("--map", required=True, type=id_arg("map"), help="map id ([A-Za-z0-9_-]+)")
        add_link_arguments(p)
        p.add_argument("--timeout", type=positive_float, default=5.0, help="reply timeout [s]")
        p.set_defaults(func=fn)
        if name == "status":
            continue
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
        add_out_arguments(p, required=False)
