"""The one Zenoh query client: status and region queries of the map service, as every process asks them.

`get_replies` sends one query (to the nearest queryable, or fanned out to every shard with
`fan_out=True`), keeps only the replies of the servers its `Trust` believes (psrmap_common.trust: the one check every
client makes; each ignored reply is logged and listed with the reason), and returns the payloads and the error
texts; `get_one` is the first good payload or a `QueryError` that says why there is none;
`get_status` is the map's decoded `Status`, or None. The CLI (`psrmap status`, `psrmap query`), the
planner's client and the mission all query through here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import msgpack
import zenoh

from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import partition_key, status_key
from protocol.messages import ScoutStatus, Status
from protocol.partition import Partition
from psrmap_common.errors import QueryError
from psrmap_common.trust import Trust, believe, trusted_ids

__all__ = [
    "QueryError",
    "Replies",
    "Trust",
    "aggregate_status",
    "get_one",
    "get_partition",
    "get_replies",
    "get_status",
    "get_statuses",
    "map_extent",
    "wait_for_server",
]

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
    trusted: Trust | Iterable[str] = (),
) -> Replies:
    """Every reply to `selector` within `timeout_s`. fan_out: ask every matching queryable (all shards)
    without consolidation; trusted: whom to believe (a `Trust`, or Zenoh ids; empty: anyone)."""
    kw: dict[str, Any] = {"timeout": timeout_s}
    if fan_out:
        kw.update(target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE)
    map_id = selector.split("?", 1)[0].split("/")[1] if selector.count("/") >= 2 else ""
    trust = Trust.of(trusted)
    ids = trusted_ids(session, map_id, trust, timeout_s)
    replies = [
        (str(r.replier_id.zid) if r.replier_id is not None else None, r) for r in session.get(selector, **kw)
    ]
    if ids is not None and trust.attested and any(z not in ids for z, _ in replies):
        ids = trusted_ids(session, map_id, trust, timeout_s)  # a server that came up while we asked
    out = Replies()
    for zid, reply in replies:
        if not believe(zid, ids, f"a reply on {selector.split('?', 1)[0]!r}"):
            out.errors.append(f"ignored a reply from {zid}, not a trusted map server")
            continue
        if reply.ok is not None:
            out.ok.append(reply.ok.payload.to_bytes())
        else:
            err = reply.err
            out.errors.append(
                err.payload.to_bytes().decode(errors="replace") if err is not None else "empty reply"
            )
    return out


def get_one(
    session: zenoh.Session, selector: str, timeout_s: float, trusted: Trust | Iterable[str] = ()
) -> bytes:
    """The first good reply to `selector`; QueryError when none came or the servers refused."""
    replies = get_replies(session, selector, timeout_s, trusted=trusted)
    if replies.ok:
        return replies.ok[0]
    if replies.errors:
        raise QueryError(f"the server refused {selector!r}: {'; '.join(replies.errors)}")
    raise QueryError(f"no reply on {selector!r} within {timeout_s:g} s (is a server for this map up?)")


def get_statuses(
    session: zenoh.Session, map_id: str, timeout_s: float = 2.0, trusted: Trust | Iterable[str] = ()
) -> list[Status]:
    """Every server's (every shard's) status of `map_id`, fanned out; undecodable replies are skipped;
    trusted: whom to believe (a `Trust`, or Zenoh ids; empty: anyone)."""
    out = []
    for payload in get_replies(session, status_key(map_id), timeout_s, fan_out=True, trusted=trusted).ok:
        try:
            st = decode(payload, expected_type="status")
        except ProtocolError as exc:
            log.warning("undecodable status reply: %s", exc)
            continue
        assert isinstance(st, Status)
        out.append(st)
    return out


def aggregate_status(parts: list[Status]) -> Status:
    """One status for a map from its shards' statuses (one per shard; an unsharded map's own is returned).

    Counters (cells, merged, duplicates, rejected, version) are sums: shards own disjoint tiles and number
    their versions on their own. A scout's `last_seq` is the number of parts merged in order over all
    shards minus one (each shard has its own seq stream of the scout); alive if any shard sees it. `health`
    holds the worst worker state, `shards_answered` and `shards_missing`."""
    if not parts:
        raise ValueError("no status to aggregate")
    if all(p.shards == 1 for p in parts):  # unsharded (several replies: one server seen over two routes)
        return max(parts, key=lambda p: p.version)
    first = parts[0]
    by_shard = {p.shard: p for p in parts}  # a shard that answered twice (two routes) counts once
    k = first.shards
    rejected: dict[str, int] = {}
    scouts: dict[str, list[ScoutStatus]] = {}
    for p in by_shard.values():
        for r, n in p.rejected.items():
            rejected[r] = rejected.get(r, 0) + n
        for name, sc in p.scouts.items():
            scouts.setdefault(name, []).append(sc)
    order = ("failed", "waiting_for_store", "ok")
    states = [str(p.health.get("worker", "ok")) for p in by_shard.values()]
    worst = min(states, key=lambda x: order.index(x) if x in order else 0)
    missing = sorted(set(range(k)) - {p.shard for p in by_shard.values()})
    health: dict[str, str | float | None] = {
        "worker": worst,
        "shards_answered": float(len(by_shard)),
        "shards_missing": ",".join(map(str, missing)) or None,
    }
    return Status(
        first.map,
        first.res,
        sum(p.version for p in by_shard.values()),
        sum(p.cells for p in by_shard.values()),
        sum(p.merged for p in by_shard.values()),
        sum(p.duplicates for p in by_shard.values()),
        rejected,
        {
            n: ScoutStatus(
                max(s.epoch for s in v), sum(s.last_seq + 1 for s in v) - 1, any(s.alive for s in v)
            )
            for n, v in scouts.items()
        },
        health,
        max(p.t for p in by_shard.values()),
        None,
        k,
        _union_bounds([p.bounds for p in by_shard.values()]),
    )


def _union_bounds(boxes: Iterable[tuple[int, int, int, int] | None]) -> tuple[int, int, int, int] | None:
    """The smallest inclusive cell box holding every given box (None ones skipped; None when none is left)."""
    got = [b for b in boxes if b is not None]
    if not got:
        return None
    return (min(b[0] for b in got), min(b[1] for b in got), max(b[2] for b in got), max(b[3] for b in got))


def get_partition(
    session: zenoh.Session, map_id: str, timeout_s: float = 2.0, trusted: Trust | Iterable[str] = ()
) -> Partition | None:
    """The map's partition as its servers publish it (`psr/<map>/partition`); None when none answered.
    Raises QueryError when servers disagree (a misconfigured deployment must not be guessed around)."""
    found: set[Partition] = set()
    for payload in get_replies(session, partition_key(map_id), timeout_s, fan_out=True, trusted=trusted).ok:
        try:
            found.add(Partition.from_dict(msgpack.unpackb(payload, raw=False)))
        except (ProtocolError, ValueError) as exc:
            log.warning("bad partition reply: %s", exc)
    if len(found) > 1:
        raise QueryError(
            f"the servers of map {map_id!r} publish different partitions: {sorted(map(str, found))}"
        )
    return found.pop() if found else None


def get_status(
    session: zenoh.Session, map_id: str, timeout_s: float = 2.0, trusted: Trust | Iterable[str] = ()
) -> Status | None:
    """The map's status — aggregated over its shards when it is sharded (`aggregate_status`) — or None when
    no server answered (or no answer was a valid status)."""
    parts = get_statuses(session, map_id, timeout_s, trusted)
    return aggregate_status(parts) if parts else None


def map_extent(statuses: list[Status], map_id: str) -> tuple[float, float, float, float]:
    """The map-frame box [m] (x0, y0, x1, y1) that holds every cell with data, from the servers' statuses
    (every shard's): what a whole-map query asks for. QueryError when none answered or the map is empty."""
    if not statuses:
        raise QueryError(f"no map server of {map_id!r} answered its status: the map's extent is unknown")
    box = aggregate_status(statuses).extent_m()
    if box is None:
        raise QueryError(f"map {map_id!r} holds no data yet: its extent is empty")
    return box


def wait_for_server(
    session: zenoh.Session,
    map_id: str,
    timeout_s: float = 10.0,
    shard: int | None = None,
    *,
    shards: int = 1,
    trusted: Trust | Iterable[str] = (),
    check: Callable[[], None] | None = None,
) -> Status | None:
    """Block until the map's servers answer a status query: every one of `shards` shards, or (`shard`) that
    shard; returns their aggregate status, None after `timeout_s`. `check` runs between attempts and may raise
    to stop waiting (a server process that died). The one wait for a server: tests, benchmarks, the mission."""
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        parts = get_statuses(session, map_id, max(0.05, min(1.0, left)), trusted)
        if shard is not None:
            parts = [p for p in parts if p.shard == shard]
        if parts and (shard is not None or len({p.shard for p in parts}) >= shards):
            return aggregate_status(parts)
        if check is not None:
            check()
        if time.monotonic() + 0.05 >= deadline:
            return None
        time.sleep(0.05)
