"""The `psrmap` console script: one subcommand per component, parsed with argparse.

Each component package owns its own subcommands in its `cli.py` (a `register(subparsers)` function
that adds parsers whose `func` default runs the command). This module only collects them, so the
components stay independent of each other.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

# Packages that contribute subcommands, in the order they are listed in `psrmap --help`.
_COMMAND_MODULES = (
    "map_server.cli",  # router, server, status, query
    "scout_agent.cli",  # scout, evaluate
    "consumer_planner.cli",  # plan, compare
    "psrmap.mission",  # mission
    "psrmap.secure",  # secure init
    "psrmap.experiments",  # experiment
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="psrmap",
        description="Proprioceptive terrain mapping for legged lunar scouts, shared over Zenoh.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:  # output piped into `head` and the reader left: not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
