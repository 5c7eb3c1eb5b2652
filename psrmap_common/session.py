"""Every process builds its Zenoh configuration here: explicit endpoints, multicast scouting off, and optionally
a Zenoh config file (credentials, TLS, access control: `psrmap secure init`)."""

from __future__ import annotations

import argparse
import ipaddress
import json
import re
import socket
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from psrmap_common.errors import InsecureListen, SessionError

if TYPE_CHECKING:
    import zenoh

# Imports inside functions here are deliberate: the light commands' --help load no Zenoh
# (tests/test_cli.py).

__all__ = [
    "MODES",
    "InsecureListen",
    "SessionError",
    "check_endpoint",
    "endpoint_arg",
    "file_endpoints",
    "free_endpoint",
    "free_port",
    "open_session",
    "why_refused",
    "zenoh_config",
]

MODES = ("peer", "client", "router")

# Zenoh locators: <protocol>/<address>[?metadata][#config]; the IP ones need HOST:PORT
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
_OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_HOST_PORT = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on `host` that was free a moment ago (the mission's router, tests, benchmarks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def free_endpoint(host: str = "127.0.0.1") -> str:
    """A `tcp/<host>:<port>` endpoint on a port that was free a moment ago."""
    return f"tcp/{host}:{free_port(host)}"


def check_endpoint(endpoint: str) -> str:
    """`endpoint` if it is a Zenoh locator psrmap can use (`tcp/HOST:PORT`, `tls/HOST:PORT`, ...), else a
    ValueError naming the form, so a typo never reaches Zenoh's config parser."""
    example = "e.g. tcp/127.0.0.1:7447"
    proto, sep, rest = endpoint.partition("/")
    addr = rest.split("?", 1)[0].split("#", 1)[0]
    if not sep:
        hint = f": did you mean tcp/{endpoint}?" if _HOST_PORT.match(endpoint) else f" ({example})"
        raise ValueError(f"endpoint {endpoint!r} has no protocol; write PROTOCOL/HOST:PORT{hint}")
    if proto in _OTHER_PROTOCOLS and addr:
        return endpoint
    if proto not in _IP_PROTOCOLS:
        raise ValueError(
            f"endpoint {endpoint!r}: unknown protocol {proto!r}; protocols: "
            f"{', '.join(_IP_PROTOCOLS + _OTHER_PROTOCOLS)} ({example})"
        )
    m = _HOST_PORT.match(addr)
    if not m or not 0 < int(m.group(2)) < 65536:
        raise ValueError(f"endpoint {endpoint!r}: need {proto}/HOST:PORT with a port 1-65535 ({example})")
    return endpoint


def endpoint_arg(text: str) -> str:
    """argparse type of `--connect`/`--listen`: one endpoint or several separated by commas, each checked."""
    try:
        for e in text.split(","):
            if e:
                check_endpoint(e)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _loopback(endpoint: str) -> bool:
    """tcp/127.0.0.1:7447, tcp/[::1]:7447, tcp/localhost:7447 are loopback; anything else is not."""
    addr = endpoint.split("/", 1)[-1].rsplit(":", 1)[0].strip("[]")
    if addr == "localhost":
        return True
    try:
        return ipaddress.ip_address(addr).is_loopback
    except ValueError:
        return False


def file_endpoints(config_file: str | Path | None, kind: str = "connect") -> tuple[str, ...]:
    """The `connect` or `listen` endpoints a Zenoh config file names (`psrmap secure init` writes the router's
    endpoint into every agent's file), () without a file; ValueError for an unreadable file."""
    if config_file is None:
        return ()
    import zenoh

    try:
        eps = json.loads(zenoh.Config.from_file(str(config_file)).get_json(f"{kind}/endpoints") or "[]")
    except (zenoh.ZError, OSError, ValueError) as exc:
        raise ValueError(f"cannot read the Zenoh config {config_file}: {exc}") from None
    return tuple(e for e in eps if isinstance(e, str)) if isinstance(eps, list) else ()


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
    for e in (*connect, *listen):
        check_endpoint(e)
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


def _authenticated(conf: zenoh.Config) -> bool:
    def get(key: str):  # type: ignore[no-untyped-def]
        try:
            return json.loads(conf.get_json(key))
        except Exception:
            return None

    usr = get("transport/auth/usrpwd") or {}
    tls = get("transport/link/tls") or {}
    return bool(usr.get("dictionary_file") or usr.get("user")) or bool(tls.get("enable_mtls"))


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """`zenoh.open(conf)`, or a SessionError saying what went wrong: nothing listens at the endpoints, or a
    router answers there but refused the session (no credentials, or not ones it accepts)."""
    import zenoh

    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise SessionError(f"cannot open a Zenoh session: {why_refused(conf)} ({exc})") from None


def why_refused(conf: zenoh.Config) -> str:
    """Why a session with `conf` could not connect, told apart by a plain TCP connect to its endpoints:
    nothing listens there, or something does and turned the session away (Zenoh reports both alike)."""
    import socket

    def get(key: str) -> Any:
        try:
            return json.loads(conf.get_json(key))
        except Exception:
            return None

    eps = [e for e in (get("connect/endpoints") or []) if isinstance(e, str)]
    answering = []
    for e in eps:
        proto, _, addr = e.partition("/")
        m = _HOST_PORT.match(addr.split("?", 1)[0].split("#", 1)[0])
        if proto in ("tcp", "tls") and m:
            try:
                with socket.create_connection((m.group(1).strip("[]"), int(m.group(2))), timeout=1.0):
                    answering.append(e)
            except OSError:
                pass
    if not answering:
        return (
            f"nothing accepts connections at {', '.join(eps) or '(no endpoint)'}; a router must be listening "
            "there: is `psrmap router --listen ...` (or `psrmap server --listen ...`) running?"
        )
    if _authenticated(conf):
        return (
            f"a router answers at {', '.join(answering)} but refused this session: it does not accept these "
            "credentials (user/password or TLS certificate; check --zenoh-config against the router's "
            "`psrmap secure init` folder)"
        )
    return (
        f"a router answers at {', '.join(answering)} but refused this session: it requires credentials; give "
        "--zenoh-config FILE (this agent's file from `psrmap secure init`)"
    )
