"""`psrmap mission`: the command's options over `MissionConfig`."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import signal
from pathlib import Path
from typing import Any

from psrmap.mission.config import MissionError, load_config, validate, with_scouts
from psrmap_common.cli_parser import Subparsers, non_negative_int, positive_float
from psrmap_common.errors import UsageError
from psrmap_common.recording import ViewerUnavailable, use_viewer

__all__ = ["register"]


def register(sub: Subparsers) -> None:
    p = sub.add_parser(
        "mission",
        help="run a whole mission: router, map server, N scouts, a planner query (embedded defaults)",
        description="Start a Zenoh router, the map server and N scouts on a seeded lunar terrain; when they are "
        "done, plan a path across the explored area and compare the scouts' routes. Everything lands in "
        "runs/<timestamp>/.",
    )
    p.add_argument("--config", help="mission TOML file (default: the embedded mission_default.toml)")
    p.add_argument("--scouts", type=int, help="number of scouts (default: as many as the config lists, 3)")
    p.add_argument("--seed", type=non_negative_int, help="terrain seed")
    p.add_argument(
        "--sim-seconds", type=positive_float, help="cap on each scout's walk [s of simulated time]"
    )
    p.add_argument("--out", help="parent folder of the run folder (default runs/)")
    p.add_argument("--run-dir", help="exact run folder (default <out>/<timestamp>)")
    p.add_argument("--no-rrd", action="store_true", help="do not write Rerun recordings")
    p.add_argument(
        "--shards",
        type=int,
        metavar="K",
        help="split the map over K map-server shards (default: the config's, 1)",
    )
    p.add_argument(
        "--tile",
        type=int,
        metavar="CELLS",
        help="the servers' storage tile, cells per side, a power of two (default 64); a shard owns whole tiles",
    )
    p.add_argument(
        "--zenoh-config",
        metavar="ROUTER.json5",
        help="use an existing `psrmap secure init` folder: its router.json5 (the agents' files beside "
        "it: server, planner and one per scout id) instead of fresh per-run credentials",
    )
    p.add_argument(
        "--no-secure",
        action="store_true",
        help="no per-run credentials and router ACL (every component talks to an open loopback router)",
    )
    p.add_argument(
        "--viewer",
        action="store_true",
        help="spawn a local Rerun viewer and stream the whole mission to it live (besides the .rrd files)",
    )
    p.add_argument(
        "--connect-viewer",
        metavar="URL",
        help="stream the mission live to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output, only the final JSON path")
    p.set_defaults(func=_cmd_mission)


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _cmd_mission(args: argparse.Namespace) -> int:
    try:
        cfg = load_config(args.config)
        if args.scouts is not None:
            cfg = with_scouts(cfg, args.scouts)
        changes: dict[str, Any] = {}
        if args.seed is not None:
            changes["seed"] = args.seed
        if args.sim_seconds is not None:
            changes["sim_seconds"] = args.sim_seconds
        if args.out is not None:
            changes["out"] = args.out
        if args.shards is not None:
            changes["shards"] = args.shards
        if args.tile is not None:
            changes["tile"] = args.tile
        if args.no_rrd:
            changes["rrd"] = False
        if args.no_secure:
            changes["secure"] = False
        if args.zenoh_config:
            changes["zenoh_config"] = args.zenoh_config
        cfg = dataclasses.replace(cfg, **changes)
        validate(cfg)
        if (args.viewer or args.connect_viewer) and not cfg.rrd:
            raise MissionError("--viewer/--connect-viewer stream the recordings: drop --no-rrd")
        use_viewer(args.viewer, args.connect_viewer)  # the components inherit PSRMAP_VIEWER_URL
    except ViewerUnavailable as exc:  # one line: nothing is wrong with the command, only the place
        raise UsageError(str(exc), usage=False) from None
    except (MissionError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    # deliberately here, not at the top: the mission imports the map server, the scout (MuJoCo, Pinocchio)
    # and the planner, which `psrmap mission --help` and a usage error need not wait for
    from psrmap.mission.run import run_mission

    # SIGTERM (a supervisor, `kill`) unwinds like Ctrl-C: run_mission's cleanup stops every component it started
    signal.signal(signal.SIGTERM, _interrupted)
    summary = run_mission(cfg, Path(args.run_dir) if args.run_dir else None, progress=not args.quiet)
    if args.quiet:
        print(Path(summary["run_dir"]) / "summary.json")
    ok = all("error" not in s for s in summary.get("scouts", {}).values())
    with contextlib.suppress(Exception):
        ok = ok and "error" not in summary["plan"]
    return 0 if ok else 1
