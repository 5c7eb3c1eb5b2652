"""`psrmap export`: a map region in the field's formats.

- `--format geotiff`: a multi-band GeoTIFF (`psrmap_interop/geotiff.py`): each layer's value and count, NaN as nodata,
  band descriptions and unit types; in `IAU_2015:30135` (Moon south polar stereographic) when the mission's
  origin on the Moon is known (`--origin LAT,LON[,HEADING]`, or `[mission] origin` of `--config`), with the
  GDAL side-car `<out>.aux.xml` that names that CRS (keep the two files together), else in a local
  engineering CRS that says so.
- `--format npz`: the map core's one `.npz` layout (`<layer>/<stat>` arrays; `mapcore.read_npz` reads it).
- `--format mcap`: a rosbag2 folder with MCAP storage (`psrmap_interop/rosbag.py`): the map as
  `grid_map_msgs/msg/GridMap` on `/psrmap/grid_map`, the planner's cost as `nav_msgs/msg/OccupancyGrid` on
  `/psrmap/cost`, and with `--run-dir` each scout's own estimate of its walk as `nav_msgs/msg/Path` on
  `/psrmap/scouts/<id>/path` (growing, one message per simulated second) and the mission's planned path on
  `/psrmap/plan`.
The region comes from the map servers (`--connect`, `--map`, and `--box`, by default the whole map: the cells
holding data, from the servers' status) or a saved map (`--npz`). The format defaults to what `--out`'s
extension says (.tif/.tiff geotiff, .mcap mcap, else npz).

`write_export` is the one writer of these files: `psrmap query --out` writes through it too.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

from protocol.keys import id_arg
from psrmap.ros2 import box_arg
from psrmap_common.cli_parser import Subparsers
from psrmap_common.errors import UsageError
from psrmap_common.link import add_link_arguments, link_from_args

if TYPE_CHECKING:
    from psrmap_interop.geotiff import MoonOrigin
    from psrmap_mapcore import LayerGrid

# Imports inside functions here are deliberate: `psrmap query --help` imports this module and loads no
# Zenoh, numpy or planner (tests/test_cli.py).

__all__ = ["FORMATS", "export_geotiff", "export_mcap", "format_of", "register", "write_export"]

FORMATS = ("geotiff", "mcap", "npz")


def format_of(out: str | Path, fmt: str | None = None) -> str:
    """`fmt` if given, else the format `out`'s extension names: .tif/.tiff geotiff, .mcap mcap, else npz."""
    if fmt is not None:
        return fmt
    low = str(out).lower()
    return "geotiff" if low.endswith((".tif", ".tiff")) else "mcap" if low.endswith(".mcap") else "npz"


def write_export(
    grid: LayerGrid,
    out: str | Path,
    fmt: str,
    origin: MoonOrigin | None = None,
    run_summary: dict | None = None,
) -> Path:
    """`grid` (a mapcore LayerGrid) written to `out` as `fmt` (one of FORMATS); `origin` (interop MoonOrigin)
    places a GeoTIFF on the Moon, `run_summary` adds a mission's paths to a rosbag2. A `UsageError` when the
    grid lacks what the format needs or a rosbag2 folder would be overwritten."""
    if fmt not in FORMATS:
        raise UsageError(f"--format {fmt!r}; formats: {', '.join(FORMATS)}")
    if fmt == "npz":
        from psrmap_mapcore import write_npz

        return write_npz(out, grid)
    from psrmap_mapcore import MapCoreError

    try:
        for name in grid.layers:
            grid.value(name)
    except MapCoreError as exc:
        raise UsageError(f"--format {fmt} needs each layer's value (--stats value,n or all): {exc}") from None
    if fmt == "geotiff":
        return export_geotiff(grid, out, origin)
    if Path(out).exists():
        raise UsageError(f"--out {out}: exists; a rosbag2 is written into a new folder")
    return export_mcap(grid, out, run_summary)


def export_geotiff(grid: LayerGrid, out: str | Path, origin: MoonOrigin | None = None) -> Path:
    """`grid` -> GeoTIFF at `out`."""
    from psrmap_interop.geotiff import write_geotiff

    xa, ya, _, _ = grid.bounds_m()
    names = [n for n in grid.layers if n != "cost"]
    return write_geotiff(out, {n: grid.value(n) for n in names}, {n: grid.count(n) for n in names}, grid.res, xa, ya,
                         origin, tags={"PSRMAP_MAP": grid.map, "PSRMAP_VERSION": str(grid.version)})  # fmt: skip


def export_mcap(
    grid: LayerGrid, out: str | Path, run_summary: dict | None = None, stamp_ns: int | None = None
) -> Path:
    """`grid` (and a mission's summary: scouts' estimated paths, the plan) -> rosbag2/MCAP folder `out`."""
    from consumer_planner.costs import build_costs
    from psrmap_interop.ros2_messages import (
        GRID_MAP,
        OCCUPANCY_GRID,
        PATH,
        grid_map_msg,
        occupancy_grid_msg,
        path_msg,
    )
    from psrmap_interop.rosbag import BagMessage, write_mcap_bag

    t0 = time.time_ns() if stamp_ns is None else stamp_ns
    xa, ya, _, _ = grid.bounds_m()
    layers = {}
    for name in grid.layers:
        layers[name] = grid.value(name)
        layers[f"{name}_count"] = grid.count(name)
    costs = build_costs(grid)
    msgs = [BagMessage("/psrmap/grid_map", GRID_MAP, grid_map_msg(layers, grid.res, xa, ya, "map", t0), t0),
            BagMessage("/psrmap/cost", OCCUPANCY_GRID, occupancy_grid_msg(costs.cost, costs.known, grid.res, xa, ya,
                                                                          "map", t0), t0)]  # fmt: skip
    if run_summary:
        for sid, s in (run_summary.get("scouts") or {}).items():
            pts = s.get("path_estimate") or []
            for k in range(1, len(pts) + 1):  # the path as it grew: one message per recorded pose
                t = t0 + int(pts[k - 1][0] * 1e9)
                msgs.append(BagMessage(f"/psrmap/scouts/{sid}/path", PATH,
                                       path_msg([p[1:] for p in pts[:k]], "map", t), t))  # fmt: skip
        plan = run_summary.get("plan") or {}
        if plan.get("path"):
            msgs.append(BagMessage("/psrmap/plan", PATH, path_msg(plan["path"], "map", t0), t0))
    return write_mcap_bag(out, msgs)


def register(sub: Subparsers) -> None:
    p = sub.add_parser("export", help="write a map region as GeoTIFF (GIS) or rosbag2/MCAP (ROS tools)",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    add_out_arguments(p)
    src = p.add_argument_group("map source (one of --connect, --npz)")
    src.add_argument("--map", type=id_arg("map"), help="map id (with --connect)")
    add_link_arguments(src)
    src.add_argument("--box", type=box_arg, metavar="X0,Y0,X1,Y1",
                     help="map area [m] (with --connect; default: the whole map)")  # fmt: skip
    src.add_argument("--npz", metavar="FILE", help="a saved map (.npz) instead of the servers")
    p.add_argument(
        "--config", metavar="MISSION.toml", help="take --origin from this mission config's [mission] origin"
    )
    p.add_argument(
        "--run-dir", metavar="DIR", help="mcap: add the scouts' estimated paths and the plan of this run"
    )
    p.set_defaults(func=_cmd)


def add_out_arguments(p: argparse.ArgumentParser, required: bool = True) -> None:
    """`--out`, `--format`, `--origin`: where and how `write_export` writes (`psrmap export`, `psrmap query`)."""
    p.add_argument(
        "--out",
        required=required,
        help="output: .npz (arrays), .tif (GeoTIFF), or a new folder (rosbag2/MCAP; must not exist)",
    )
    p.add_argument(
        "--format",
        choices=FORMATS,
        help="geotiff (GIS), mcap (rosbag2 for ROS tools) or npz (numpy arrays); default from --out's "
        "extension: .tif/.tiff geotiff, .mcap mcap, else npz",
    )
    p.add_argument(
        "--origin",
        metavar="LAT,LON[,HEADING]",
        help="geotiff: the map origin on the Moon [deg]; the file is then in IAU_2015:30135 (else a local frame)",
    )


def origin_from_args(args: argparse.Namespace) -> MoonOrigin | None:
    """The `--origin` (or `--config`'s [mission] origin) as an interop MoonOrigin, None without one."""
    from psrmap_interop.geotiff import MoonOrigin

    try:
        if args.origin:
            return MoonOrigin.parse(args.origin)
        if getattr(args, "config", None):
            from psrmap.mission.config import load_config

            o = load_config(args.config).origin
            return MoonOrigin(*o) if o else None
    except ValueError as exc:  # a bad --origin; MissionError (a ValueError): a bad --config
        raise UsageError(str(exc)) from None
    return None


def _cmd(args: argparse.Namespace) -> int:
    from psrmap_interop.geotiff import pam_path

    origin = origin_from_args(args)
    fmt = format_of(args.out, args.format)
    if fmt == "mcap" and Path(args.out).exists():  # before any query
        raise UsageError(f"--out {args.out}: exists; a rosbag2 is written into a new folder")
    grid = _load(args)
    summary = None
    if args.run_dir:
        f = Path(args.run_dir) / "summary.json"
        if not f.exists():
            raise UsageError(
                f"--run-dir {args.run_dir}: no summary.json (give a `psrmap mission` run folder)"
            )
        summary = json.loads(f.read_text())
    out = write_export(grid, args.out, fmt, origin, summary)
    geo = origin is not None and fmt == "geotiff"
    print(json.dumps({"format": fmt, "out": str(out), "map": grid.map, "version": grid.version,
                      "layers": list(grid.layers), "w": grid.w, "h": grid.h, "res": grid.res,
                      "crs": "IAU_2015:30135" if geo else None,
                      "crs_sidecar": str(pam_path(out)) if geo else None}))  # fmt: skip
    return 0


def _load(args: argparse.Namespace) -> LayerGrid:
    from consumer_planner.errors import PlannerError
    from psrmap_mapcore import MapFileError, read_npz

    link = link_from_args(args, required=False)
    if (args.npz is None) == (not link.connect):
        raise UsageError("give either --connect ENDPOINT (with --map ID) or --npz FILE")
    if args.npz:
        try:
            return read_npz(args.npz, map_id=args.map or "local")
        except MapFileError as exc:
            raise UsageError(str(exc)) from None
    if not args.map:
        raise UsageError("--connect needs --map ID")
    from consumer_planner.client import ClientConfig, MapClient

    cfg = ClientConfig(connect=link.connect, zenoh_config=link.zenoh_config)
    try:
        with MapClient(cfg) as client:
            return client.region(args.map, args.box)
    except PlannerError as exc:
        raise UsageError(str(exc)) from None
