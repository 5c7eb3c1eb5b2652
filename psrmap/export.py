"""`psrmap export`: a map region in the field's formats.

- `--format geotiff`: a multi-band GeoTIFF (`interop/geotiff.py`): each layer's value and count, NaN as nodata,
  band descriptions and unit types; in `IAU_2015:30135` (Moon south polar stereographic) when the mission's
  origin on the Moon is known (`--origin LAT,LON[,HEADING]`, or `[mission] origin` of `--config`), with the
  GDAL side-car `<out>.aux.xml` that names that CRS (keep the two files together), else in a local
  engineering CRS that says so.
- `--format mcap`: a rosbag2 folder with MCAP storage (`interop/rosbag.py`): the map as
  `grid_map_msgs/msg/GridMap` on `/psrmap/grid_map`, the planner's cost as `nav_msgs/msg/OccupancyGrid` on
  `/psrmap/cost`, and with `--run-dir` each scout's own estimate of its walk as `nav_msgs/msg/Path` on
  `/psrmap/scouts/<id>/path` (growing, one message per simulated second) and the mission's planned path on
  `/psrmap/plan`.
The region comes from the map servers (`--connect`, `--map`, and `--box`, by default the whole map: the cells
holding data, from the servers' status) or a saved map (`--npz`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

__all__ = ["export_geotiff", "export_mcap", "register"]

FORMATS = ("geotiff", "mcap")


def export_geotiff(grid: Any, out: str | Path, origin: Any = None) -> Path:
    """`grid` (consumer_planner LayerGrid) -> GeoTIFF at `out`."""
    from interop.geotiff import write_geotiff

    xa, ya, _, _ = grid.bounds_m()
    names = [n for n in grid.layers if n != "cost"]
    return write_geotiff(out, {n: grid.value(n) for n in names}, {n: grid.count(n) for n in names}, grid.res, xa, ya,
                         origin, tags={"PSRMAP_MAP": grid.map, "PSRMAP_VERSION": str(grid.version)})  # fmt: skip


def export_mcap(
    grid: Any, out: str | Path, run_summary: dict | None = None, stamp_ns: int | None = None
) -> Path:
    """`grid` (and a mission's summary: scouts' estimated paths, the plan) -> rosbag2/MCAP folder `out`."""
    from consumer_planner.costs import build_costs
    from interop.ros2_messages import (
        GRID_MAP,
        OCCUPANCY_GRID,
        PATH,
        grid_map_msg,
        occupancy_grid_msg,
        path_msg,
    )
    from interop.rosbag import BagMessage, write_mcap_bag

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


def register(sub: Any) -> None:
    from common.session import endpoint_arg
    from protocol.keys import id_arg
    from psrmap.ros2 import box_arg

    p = sub.add_parser("export", help="write a map region as GeoTIFF (GIS) or rosbag2/MCAP (ROS tools)",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument(
        "--format", required=True, choices=FORMATS, help="geotiff (GIS) or mcap (rosbag2 for ROS tools)"
    )
    p.add_argument("--out", required=True, help="output file (.tif) or rosbag2 folder (mcap; must not exist)")
    src = p.add_argument_group("map source (one of --connect, --npz)")
    src.add_argument("--map", type=id_arg("map"), help="map id (with --connect)")
    src.add_argument(
        "--connect",
        type=endpoint_arg,
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh router endpoint",
    )
    src.add_argument("--box", type=box_arg, metavar="X0,Y0,X1,Y1",
                     help="map area [m] (with --connect; default: the whole map)")  # fmt: skip
    src.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh config with credentials (`psrmap secure init`)"
    )
    src.add_argument("--npz", metavar="FILE", help="a saved map (.npz) instead of the servers")
    p.add_argument(
        "--origin",
        metavar="LAT,LON[,HEADING]",
        help="the map origin on the Moon [deg]: GeoTIFF in IAU_2015:30135 (else a local frame)",
    )
    p.add_argument(
        "--config", metavar="MISSION.toml", help="take --origin from this mission config's [mission] origin"
    )
    p.add_argument(
        "--run-dir", metavar="DIR", help="mcap: add the scouts' estimated paths and the plan of this run"
    )
    p.set_defaults(func=_cmd, parser=p)


def _cmd(args: argparse.Namespace) -> int:
    from interop.geotiff import MoonOrigin, pam_path

    origin = None
    try:
        if args.origin:
            origin = MoonOrigin.parse(args.origin)
        elif args.config:
            from psrmap.mission import MissionError, load_config

            try:
                o = load_config(args.config).origin
            except MissionError as exc:
                args.parser.error(str(exc))
            origin = MoonOrigin(*o) if o else None
    except ValueError as exc:
        args.parser.error(str(exc))
    if args.format == "mcap" and Path(args.out).exists():
        args.parser.error(f"--out {args.out}: exists; a rosbag2 is written into a new folder")
    grid = _load(args)
    summary = None
    if args.run_dir:
        f = Path(args.run_dir) / "summary.json"
        if not f.exists():
            args.parser.error(
                f"--run-dir {args.run_dir}: no summary.json (give a `psrmap mission` run folder)"
            )
        summary = json.loads(f.read_text())
    out = (
        export_geotiff(grid, args.out, origin)
        if args.format == "geotiff"
        else export_mcap(grid, args.out, summary)
    )
    print(json.dumps({"format": args.format, "out": str(out), "map": grid.map, "version": grid.version,
                      "layers": list(grid.layers), "w": grid.w, "h": grid.h, "res": grid.res,
                      "crs": "IAU_2015:30135" if origin and args.format == "geotiff" else None,
                      "crs_sidecar": str(pam_path(out)) if origin and args.format == "geotiff" else None}))  # fmt: skip
    return 0


def _load(args: argparse.Namespace) -> Any:
    from consumer_planner.errors import PlannerError
    from mapcore import MapFileError, read_npz

    if (args.npz is None) == (not args.connect):
        args.parser.error("give either --connect ENDPOINT (with --map ID) or --npz FILE")
    if args.npz:
        try:
            return read_npz(args.npz, map_id=args.map or "local")
        except MapFileError as exc:
            args.parser.error(str(exc))
    if not args.map:
        args.parser.error("--connect needs --map ID")
    from consumer_planner.client import ClientConfig, MapClient

    cfg = ClientConfig(connect=tuple(args.connect), zenoh_config=args.zenoh_config)
    try:
        with MapClient(cfg) as client:
            return client.region(args.map, args.box)
    except PlannerError as exc:
        args.parser.error(str(exc))
