"""`python -m consumer_planner plan|compare ...` (same as `psrmap plan|compare ...`)."""

from __future__ import annotations

import sys

from common.cli_parser import Parser, run_command
from consumer_planner.cli import register


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="consumer_planner")
    register(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    return run_command(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
