"""`python -m consumer_planner plan|compare ...` (same as `psrmap plan|compare ...`)."""

from __future__ import annotations

import sys

from consumer_planner.cli import register
from psrmap_common.cli_parser import Parser, run_command


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="consumer_planner")
    register(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    return run_command(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
