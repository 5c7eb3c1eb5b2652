"""Whose replies a client believes: the one trust check of every client (status, query, plan, compare, export,
ros2, the scout's partition discovery, the mission).

A map server holds the liveliness token `psr/<map>/serverid/<its Zenoh id>` (protocol.keys.server_id_key); in a
deployment from `psrmap secure init` the router lets only server credentials declare it, so the ids these tokens
name are the map's servers. A `Trust` says what to believe:
- `attested`: the ids of the live `serverid` tokens (what `servers.json` beside an agent's Zenoh config asks);
- `zids`: ids believed outright (a deployment without the router's ACL, where tokens prove nothing);
- neither: anyone (an open, unsecured deployment — as before trust was configured).
Replies and tile-change notices from other ids are ignored, each with a log line naming the id and why.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import zenoh

from protocol.keys import server_id_pattern

__all__ = ["Trust", "TrustedIds", "believe", "load_trust", "trusted_ids"]

log = logging.getLogger(__name__)

SERVERS_FILE = "servers.json"


@dataclass(frozen=True)
class Trust:
    attested: bool = False  # believe the ids the map's `serverid` tokens name (server credentials only)
    zids: tuple[str, ...] = ()  # Zenoh ids believed outright
    source: str = ""  # where this trust came from (for messages)

    @property
    def open(self) -> bool:
        """True when anyone is believed (no trust configured)."""
        return not self.attested and not self.zids

    @staticmethod
    def of(value: Trust | Iterable[str] | None) -> Trust:
        """A Trust from a Trust, or from Zenoh ids to believe outright (empty: anyone)."""
        if isinstance(value, Trust):
            return value
        return Trust(zids=tuple(str(z) for z in value or ()), source="given ids")


def load_trust(path: str | Path | None = None, zenoh_config: str | Path | None = None) -> Trust:
    """The trust a client's files ask for: `path` (a `servers.json`; ValueError when it is missing or not one),
    else the `servers.json` beside `zenoh_config` if there is one, else open trust.

    `servers.json` from `psrmap secure init` is {"map", "servers", "trust": "attested"}; an older one,
    {name: pinned Zenoh id}, is read as ids to believe outright."""
    if path is None:
        if zenoh_config is None:
            return Trust()
        beside = Path(zenoh_config).with_name(SERVERS_FILE)
        if not beside.is_file():
            return Trust()
        path = beside
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--trust-servers {p}: no such file (psrmap secure init writes {SERVERS_FILE})")
    try:
        data = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{p}: not a {SERVERS_FILE}: {exc}") from None
    if isinstance(data, dict) and data.get("trust") == "attested":
        return Trust(attested=True, source=str(p))
    if isinstance(data, dict) and data and all(isinstance(v, str) for v in data.values()):
        return Trust(zids=tuple(data.values()), source=str(p))
    raise ValueError(
        f'{p}: not a {SERVERS_FILE}: want {{"map", "servers", "trust": "attested"}} (psrmap secure init) '
        "or {name: Zenoh id}"
    )


def trusted_ids(
    session: zenoh.Session, map_id: str, trust: Trust, timeout_s: float = 2.0
) -> frozenset[str] | None:
    """The Zenoh ids to believe now (None: anyone): the explicit ones, and with `attested` the ids of the live
    `serverid` tokens of `map_id` (a liveliness query, answered by the router)."""
    if trust.open:
        return None
    ids = set(trust.zids)
    if trust.attested:
        for reply in session.liveliness().get(server_id_pattern(map_id), timeout=timeout_s):
            if reply.ok is not None:
                ids.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return frozenset(ids)


def believe(zid: str | None, ids: frozenset[str] | None, what: str) -> bool:
    """True when `zid` is one to believe; else logs which `what` (a reply, a notice) was ignored and why."""
    if ids is None:
        return True
    if zid is not None and zid in ids:
        return True
    why = "it carries no sender id" if zid is None else "it is not an attested or pinned map server"
    log.warning("ignored %s from Zenoh id %s: %s (trusted: %s)", what, zid, why, sorted(ids) or "none up")
    return False


class TrustedIds:
    """The ids to believe, kept current by a liveliness subscriber on the map's `serverid` tokens (servers
    coming and going, each start with a fresh id): for callbacks that may not block on a query (notices).

        with TrustedIds(session, map_id, trust) as ids:
            if ids.believe(zid, "a tile-change notice"): ...
    """

    def __init__(self, session: zenoh.Session, map_id: str, trust: Trust) -> None:
        self.trust = trust
        self._live: set[str] = set()
        self._lock = threading.Lock()
        self._sub = None
        if trust.attested:
            # changes from now on, then what is up already: a liveliness get is not reliable while the same
            # session holds a `history=True` liveliness subscriber on intersecting keys (zenoh 1.10: about 1
            # get in 300 came back empty), so the history comes from a get, never from the subscriber
            self._sub = session.liveliness().declare_subscriber(server_id_pattern(map_id), self._on)
            for zid in trusted_ids(session, map_id, Trust(attested=True)) or ():
                with self._lock:
                    self._live.add(zid)

    def _on(self, sample: zenoh.Sample) -> None:
        zid = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._live.add(zid)
            else:
                self._live.discard(zid)

    def ids(self) -> frozenset[str] | None:
        if self.trust.open:
            return None
        with self._lock:
            return frozenset(self._live) | frozenset(self.trust.zids)

    def believe(self, zid: str | None, what: str) -> bool:
        return believe(zid, self.ids(), what)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def __enter__(self) -> TrustedIds:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
