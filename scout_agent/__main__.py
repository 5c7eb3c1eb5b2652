"""`python -m scout_agent …` runs the scout commands (same as `psrmap scout …`)."""

from __future__ import annotations

import sys

from psrmap_common.cli_parser import Parser, run_command
from scout_agent.cli import register


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="python -m scout_agent")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    register(sub)
    return run_command(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
