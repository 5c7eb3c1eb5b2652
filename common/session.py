"""Every process builds its Zenoh configuration here: explicit endpoints, multicast scouting off, and optionally
a Zenoh config file (credentials, TLS, access control: `psrmap secure init`)."""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from common.errors import InsecureListen, SessionError

__all__ = ["MODES", "InsecureListen", "SessionError", "open_session", "zenoh_config"]

MODES = ("peer", "client", "router")


def _loopback(endpoint: str) -> bool:
    """tcp/127.0.0.1:7447, tcp/[::1]:7447, tcp/localhost:7447 are loopback; anything else is not."""
    addr = endpoint.split("/", 1)[-1].rsplit(":", 1)[0].strip("[]")
    if addr == "localhost":
        return True
    try:
        return ipaddress.ip_address(addr).is_loopback
    except ValueError:
        return False


def zenoh_config(
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    mode: str | None = None,
    config_file: str | Path | None = None,
    insecure: bool = False,
):
    """A `zenoh.Config`: from `config_file` (a Zenoh JSON5 config, e.g. one `psrmap secure init` wrote) if given,
    else empty; `mode` (default: the file's, else peer) and non-empty `connect`/`listen` override the file's.

    Raises `InsecureListen` when the result listens on a non-loopback endpoint with neither user/password
    authentication nor mutual TLS, unless `insecure`; ValueError for an unreadable file or unknown mode."""
    import zenoh

    if mode is not None and mode not in MODES:
        raise ValueError(f"mode {mode!r}; modes: {', '.join(MODES)}")
    if config_file is not None:
        try:
            conf = zenoh.Config.from_file(str(config_file))
        except (zenoh.ZError, OSError, ValueError) as exc:
            raise ValueError(f"cannot read the Zenoh config {config_file}: {exc}") from None
    else:
        conf = zenoh.Config()
        mode = mode or "peer"
    if mode is not None:
        conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if connect or config_file is None:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen or config_file is None:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if not insecure:
        eps = json.loads(conf.get_json("listen/endpoints") or "[]")
        eps = eps if isinstance(eps, list) else []
        open_eps = [e for e in eps if isinstance(e, str) and not _loopback(e)]
        if open_eps and not _authenticated(conf):
            raise InsecureListen(
                f"refusing to listen on {', '.join(open_eps)} without credentials: give --zenoh-config FILE "
                "(from `psrmap secure init`), listen on a loopback endpoint (tcp/127.0.0.1:PORT), or "
                "--insecure to accept anyone on that network"
            )
    return conf


def _authenticated(conf) -> bool:  # type: ignore[no-untyped-def]
    def get(key: str):  # type: ignore[no-untyped-def]
        try:
            return json.loads(conf.get_json(key))
        except Exception:
            return None

    usr = get("transport/auth/usrpwd") or {}
    tls = get("transport/link/tls") or {}
    return bool(usr.get("dictionary_file") or usr.get("user")) or bool(tls.get("enable_mtls"))


def open_session(conf: Any) -> Any:
    """`zenoh.open(conf)`, or a SessionError saying what went wrong (endpoints look like tcp/HOST:PORT;
    to connect, a router must be listening there)."""
    import zenoh

    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise SessionError(f"cannot open a Zenoh session: {exc}") from None
