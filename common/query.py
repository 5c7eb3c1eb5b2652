"""The one Zenoh query client: status and region queries of the map service, as every process asks them.

`get_replies` sends one query (to the nearest queryable, or fanned out to every shard with
`fan_out=True`), keeps only the replies of trusted servers when ids are given, and returns the payloads
and the error texts; `get_one` is the first good payload or a `QueryError` that says why there is none;
`get_status` is the map's decoded `Status`, or None. The CLI (`psrmap status`, `psrmap query`), the
planner's client and the mission all query through here.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common.errors import QueryError
from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import status_key
from protocol.messages import Status

__all__ = ["QueryError", "Replies", "get_one", "get_replies", "get_status"]

log = logging.getLogger(__name__)


@dataclass
class Replies:
    ok: list[bytes] = field(default_factory=list)  # payloads of the good replies
    errors: list[str] = field(default_factory=list)  # what each refusal or ignored reply said


def get_replies(
    session: zenoh.Session,
    selector: str,
    timeout_s: float,
    *,
    fan_out: bool = False,
    trusted: Iterable[str] = (),
) -> Replies:
    """Every reply to `selector` within `timeout_s`. fan_out: ask every matching queryable (all shards)
    without consolidation; trusted: Zenoh ids of the servers to believe (empty: any)."""
    kw: dict[str, Any] = {"timeout": timeout_s}
    if fan_out:
        kw.update(target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE)
    trust = set(trusted)
    out = Replies()
    for reply in session.get(selector, **kw):
        if trust:
            rid = reply.replier_id
            zid = str(rid.zid) if rid is not None else None
            if zid not in trust:
                out.errors.append(f"ignored a reply from {zid}, not a trusted map server")
                log.warning("ignored a reply from %s: not one of the trusted servers %s", zid, sorted(trust))
                continue
        if reply.ok is not None:
            out.ok.append(reply.ok.payload.to_bytes())
        else:
            err = reply.err
            out.errors.append(
                err.payload.to_bytes().decode(errors="replace") if err is not None else "empty reply"
            )
    return out


def get_one(session: zenoh.Session, selector: str, timeout_s: float) -> bytes:
    """The first good reply to `selector`; QueryError when none came or the servers refused."""
    replies = get_replies(session, selector, timeout_s)
    if replies.ok:
        return replies.ok[0]
    if replies.errors:
        raise QueryError(f"the server refused {selector!r}: {'; '.join(replies.errors)}")
    raise QueryError(f"no reply on {selector!r} within {timeout_s:g} s (is a server for this map up?)")


def get_status(session: zenoh.Session, map_id: str, timeout_s: float = 2.0) -> Status | None:
    """The map's status, or None when no server answered (or the answer was not a valid status)."""
    try:
        msg = decode(get_one(session, status_key(map_id), timeout_s), expected_type="status")
    except (QueryError, ProtocolError):
        return None
    assert isinstance(msg, Status)
    return msg
