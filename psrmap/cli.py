"""The `psrmap` console script: one subcommand per component, parsed with argparse.

Each component package owns its own subcommands in its `cli.py` (a `register(subparsers)` function
that adds parsers whose `func` default runs the command). This module only collects them, so the
components stay independent of each other.

Start-up stays fast: `COMMANDS` names each command's module and one-line help, and only the module of the
command being run is imported (the simulator, Pinocchio and Rerun load only for the commands that use
them); `psrmap --help` imports none. `tests/test_cli.py` checks that the table matches what each module
registers.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from psrmap.errors import exit_code_for
from psrmap_common.cli_parser import Parser, usage_exit
from psrmap_common.errors import UsageError

# command -> (module whose `register` adds it, its one-line help), in `psrmap --help` order
COMMANDS: dict[str, tuple[str, str]] = {
    "router": ("map_server.cli", "run an embedded Zenoh router"),
    "server": ("map_server.cli", "run the map server of one map"),
    "remove": (
        "map_server.cli",
        "remove one scout's (or epoch's) contributions from a stopped server's --db, exactly",
    ),
    "status": ("psrmap.client_cli", "print a map server's status"),
    "query": ("psrmap.client_cli", "query a box of the map"),
    "scout": ("scout_agent.cli", "walk a simulated Aliengo (ramps or lunar terrain)"),
    "evaluate": ("scout_agent.cli", "run one scout and score its map and detectors against ground truth"),
    "plan": ("consumer_planner.cli", "cheapest path on the shared map, with its breakdown"),
    "compare": ("consumer_planner.cli", "breakdowns of given routes on the shared map"),
    "mission": (
        "psrmap.mission",
        "run a whole mission: router, map server, N scouts, a planner query (embedded defaults)",
    ),
    "ros2": ("psrmap.ros2", "publish the shared map, cost grid and plan to ROS 2 (rmw_zenoh)"),
    "export": ("psrmap.export", "write a map region as GeoTIFF (GIS) or rosbag2/MCAP (ROS tools)"),
    "secure": ("psrmap.secure", "credentials and access control for a mission's Zenoh network"),
    "experiment": ("psrmap.experiments", "reproduce the seed paper's experiments (and the map-utility one)"),
}


def _wanted(argv: Sequence[str]) -> str | None:
    """The command named on the command line (the first word that is not an option), if any."""
    for a in argv:
        if not a.startswith("-"):
            return a
    return None


def build_parser(argv: Sequence[str] | None = None, full: bool = False) -> argparse.ArgumentParser:
    """The parser for `argv`: the named command's module registers its real parsers; every other command
    is a placeholder with its help line (`full`: import and register every module)."""
    parser = Parser(
        prog="psrmap",
        description="Proprioceptive terrain mapping for legged lunar scouts, shared over Zenoh.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = _wanted(sys.argv[1:] if argv is None else argv)
    modules = (
        {m for m, _ in COMMANDS.values()} if full else {COMMANDS[wanted][0]} if wanted in COMMANDS else set()
    )
    for module in dict.fromkeys(m for m, _ in COMMANDS.values()):
        if module in modules:
            importlib.import_module(module).register(sub)
    for name, (module, helptext) in COMMANDS.items():
        if module not in modules:
            sub.add_parser(name, help=helptext, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        result = args.func(args)
        sys.stdout.flush()
    except UsageError as exc:  # the arguments do not go together: that command's usage, exit 2
        usage_exit(parser, sys.argv[1:] if argv is None else argv, str(exc), exc.usage)
    except BrokenPipeError:  # output piped into `head` and the reader left: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print(f"psrmap {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one mapping from every package's root exception to a message and exit code
        code = exit_code_for(exc)
        if code is None and isinstance(exc, RuntimeError) and "gRPC" in str(exc):
            # Rerun's live stream: what answers at --connect-viewer is not (or no longer) a viewer
            print(
                f"psrmap {args.command}: error: the live Rerun viewer stream failed ({exc})", file=sys.stderr
            )
            return 1
        if code is None:
            raise
        print(f"psrmap {args.command}: error: {exc}", file=sys.stderr)
        return code
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
