"""The flags every client of the map service shares, declared once: `--connect` and `--zenoh-config`.

`add_link_arguments` puts them on a command's parser (the same names, types, defaults and help in every
command: `tests/test_cli.py` checks it), `link_from_args` turns them into a `Link`: the endpoints given (each
checked by `psrmap_common.session.endpoint_arg`, commas allowed), else the router the `--zenoh-config` file names
(`psrmap secure init` writes it into every agent's file), else — when the command needs one — a `UsageError`
saying what to give.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from psrmap_common.errors import SessionError, UsageError
from psrmap_common.session import endpoint_arg, file_endpoints, open_session, zenoh_config

if TYPE_CHECKING:
    import zenoh

__all__ = [
    "CONNECT_HELP",
    "ZENOH_CONFIG_HELP",
    "Link",
    "add_link_arguments",
    "link_from_args",
    "split_endpoints",
]

CONNECT_HELP = (
    "Zenoh endpoint of the map service's router, e.g. tcp/127.0.0.1:7447 (repeatable or comma-separated; "
    "default: the one the --zenoh-config file names)"
)
ZENOH_CONFIG_HELP = "Zenoh config with this agent's credentials (`psrmap secure init` writes one per agent)"
NO_ROUTER = "give --connect tcp/HOST:PORT (a router), or a --zenoh-config file that names one"


@dataclass(frozen=True)
class Link:
    """How a process reaches the map service: router endpoints and the Zenoh config file with its credentials
    (None: an open network)."""

    connect: tuple[str, ...] = ()
    zenoh_config: str | None = None


def add_link_arguments(parser: argparse._ActionsContainer, listens: bool = False) -> None:
    """`--connect ENDPOINT` (repeatable) and `--zenoh-config FILE` on `parser` (a parser or an argument group);
    `listens`: also `--insecure`, for what listens on an endpoint (router, server)."""
    parser.add_argument(
        "--connect", type=endpoint_arg, action="append", default=[], metavar="ENDPOINT", help=CONNECT_HELP
    )
    parser.add_argument("--zenoh-config", metavar="FILE", help=ZENOH_CONFIG_HELP)
    if listens:
        parser.add_argument(
            "--insecure",
            action="store_true",
            help="allow listening on a non-loopback endpoint without credentials",
        )


def split_endpoints(values: Sequence[str] | None) -> tuple[str, ...]:
    """Repeated and comma-separated endpoint flags as one tuple."""
    return tuple(e for v in values or () for e in v.split(",") if e)


def link_from_args(args: argparse.Namespace, required: bool = True) -> Link:
    """The parsed link flags as a `Link`: `--connect`, else the router `--zenoh-config` names; a `UsageError`
    for an unreadable config file, or (`required`) when neither names a router."""
    file = getattr(args, "zenoh_config", None)
    connect = split_endpoints(getattr(args, "connect", None))
    if not connect and file is not None:
        try:
            connect = file_endpoints(file, "connect")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    if required and not connect:
        raise UsageError(NO_ROUTER)
    return Link(connect, file)


def open_link(
    link: Link, mode: str = "client", listen: Sequence[str] = (), insecure: bool = False
) -> zenoh.Session:
    """A Zenoh session on `link` (`mode` unless its config file names one), or a `UsageError` naming what would
    have worked: an unreadable config, an open listen without credentials, nothing listening at the endpoints."""
    try:
        conf = zenoh_config(
            link.connect, listen, None if link.zenoh_config else mode, link.zenoh_config, insecure
        )
        return open_session(conf)
    except (ValueError, SessionError) as exc:
        raise UsageError(str(exc)) from None
