"""The scout's link to the map service: the only module of `scout_agent` that talks to Zenoh.

`ScoutPublisher` opens a client session to the given endpoints and wires the pieces together:
`delivery.DeltaPublisher` (seq numbering, unacknowledged buffer, resend; no Zenoh in it) over a
`ZenohTransport` (reliable puts with blocking congestion control), and `ScoutLink`
(acks on `psr/<map>/ack/<scout>`, resend when the server's liveliness token (re)appears, the scout's own
liveliness token `psr/<map>/alive/<scout>`). Use it as a context manager; call `poll()` from the run loop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import ack_key, alive_key, server_who
from protocol.messages import Ack
from protocol.partition import Partition
from psrmap_common.errors import QueryError
from psrmap_common.query import get_partition
from psrmap_common.session import why_refused, zenoh_config
from psrmap_common.trust import load_trust
from scout_agent.delivery import DeltaPublisher, UnackedBufferFull, new_epoch
from scout_agent.errors import ScoutConfigError, ScoutLinkError
from scout_agent.outbox import SQLiteOutbox

__all__ = ["ScoutLink", "ScoutPublisher", "ZenohTransport"]

log = logging.getLogger(__name__)


@dataclass
class _Lane:
    """What the scout keeps per shard: its seq stream, its outbox, its ack subscription."""

    shard: int | None
    publisher: DeltaPublisher
    link: ScoutLink
    outbox: SQLiteOutbox | None
    resumed: int


def shard_outbox_path(outbox: str | Path, shard: int | None) -> Path:
    """The outbox file of one shard's stream: the given path for an unsharded map, `<stem>.shard<i><suffix>`."""
    p = Path(outbox)
    return p if shard is None else p.with_name(f"{p.stem}.shard{shard}{p.suffix}")


class ScoutPublisher:
    """Publishes a scout's cell deltas to map `map_id` over Zenoh, with acks and resend.

    A sharded map (protocol.partition, discovered from `psr/<map>/partition` unless given) gets one lane per
    shard: each delta is split by tile, each part goes to its shard's key with that shard's own seq stream,
    outbox and acks, so exactly-once holds per (scout, epoch, shard, seq)."""

    def __init__(
        self,
        map_id: str,
        scout_id: str,
        res: float,
        connect: Sequence[str],
        *,
        mode: str = "client",
        max_unacked: int = 4096,
        resend_after_s: float = 1.0,
        outbox: str | Path | None = None,
        resume: bool = False,
        zenoh_config_file: str | None = None,
        partition: Partition | None = None,
        discover_timeout_s: float = 3.0,
    ) -> None:
        """outbox: SQLite file where each delta is kept until acknowledged (None: memory only). resume: resend
        what the outbox holds from an earlier run under its original epoch first; without it, an outbox that
        still holds deltas is refused (they would be silently abandoned). partition: the map's partition
        (None: ask the map's servers for it; no answer within `discover_timeout_s`: an unsharded map)."""
        if not connect:
            raise ScoutConfigError("no endpoint to connect to; give one like tcp/127.0.0.1:7447")
        if resume and outbox is None:
            raise ScoutConfigError("--resume needs an outbox (--outbox PATH) to resume from")
        conf = zenoh_config(list(connect), (), None if zenoh_config_file else mode, zenoh_config_file)
        try:
            self._session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ScoutLinkError(
                f"cannot reach the map service's router at {', '.join(connect)}: {why_refused(conf)} ({exc})"
            ) from None
        if partition is None:
            try:
                trust = load_trust(None, zenoh_config_file)  # only the map's servers say how it is split
                partition = get_partition(self._session, map_id, discover_timeout_s, trust)
            except (QueryError, ValueError) as exc:
                self._session.close()
                raise ScoutLinkError(str(exc)) from None
            if partition is None:
                log.warning(
                    "no server of map %s published its partition within %.1f s: publishing as to an unsharded "
                    "map (give the partition explicitly if the map is sharded)", map_id, discover_timeout_s,
                )  # fmt: skip
                partition = Partition()
        self.partition = partition
        shards: list[int | None] = [None] if partition.shards == 1 else list(range(partition.shards))
        self.transport = ZenohTransport(self._session)
        self.lanes: dict[int, _Lane] = {}
        epoch = new_epoch()
        try:
            for k in shards:
                self.lanes[0 if k is None else k] = self._lane(
                    k,
                    map_id,
                    scout_id,
                    res,
                    epoch,
                    max_unacked,
                    resend_after_s,
                    outbox,
                    resume,
                    first=not self.lanes,
                )
        except Exception:
            self.close()
            raise
        self.resumed = sum(lane.resumed for lane in self.lanes.values())
        self.deferred = 0  # sends refused because an unacknowledged buffer was full

    def _lane(
        self, shard: int | None, map_id: str, scout_id: str, res: float, epoch: int, max_unacked: int,
        resend_after_s: float, outbox: str | Path | None, resume: bool, first: bool,
    ) -> _Lane:  # fmt: skip
        path = shard_outbox_path(outbox, shard) if outbox is not None else None
        box = SQLiteOutbox(path) if path is not None else None
        old = box.pending() if box is not None else {}
        if old and not resume:
            n = sum(len(v) for v in old.values())
            box.close()  # type: ignore[union-attr]
            raise ScoutConfigError(
                f"outbox {path} holds {n} unacknowledged deltas of epoch(s) {', '.join(map(str, old))} from an "
                "earlier run; give --resume to send them, or move the file away to discard them"
            )
        pub = DeltaPublisher(
            self.transport, map_id, scout_id, res, epoch=epoch, max_unacked=max_unacked,
            resend_after_s=resend_after_s, outbox=box, resume=old, shard=shard,
        )  # fmt: skip
        resumed = sum(len(v) for v in old.values())
        if old:
            log.info("resuming %d unacknowledged deltas of epoch(s) %s (shard %s)", resumed, list(old), shard)
            pub.resend_all()
        link = ScoutLink(self._session, pub, shard=shard, token=first)
        return _Lane(shard, pub, link, box, resumed)

    @property
    def publisher(self) -> DeltaPublisher:
        """The first lane's publisher (the only one of an unsharded map)."""
        return next(iter(self.lanes.values())).publisher

    @property
    def link(self) -> ScoutLink:
        """The first lane's link (the only one of an unsharded map)."""
        return next(iter(self.lanes.values())).link

    @property
    def unacked(self) -> int:
        return sum(lane.publisher.unacked for lane in self.lanes.values())

    @property
    def full(self) -> bool:
        return any(lane.publisher.full for lane in self.lanes.values())

    def send(self, layers: Mapping[str, Mapping[str, np.ndarray]], t: float) -> int | None:
        """Publish one delta (split by shard); None (and nothing sent) when a shard's unacknowledged buffer
        that this delta needs is full. Returns the number of parts sent (1 on an unsharded map)."""
        if len(self.lanes) == 1:
            parts: dict[int, Mapping[str, Mapping[str, np.ndarray]]] = {0: layers}
        else:
            parts = dict(self.partition.split(layers))
            if not parts:
                return 0
        if any(self.lanes[k].publisher.full for k in parts):
            self.deferred += 1
            return None
        for k, part in parts.items():
            try:
                self.lanes[k].publisher.send(part, t)
            except UnackedBufferFull:  # (checked above; a concurrent send could only come from this thread)
                self.deferred += 1
                return None
        return len(parts)

    def poll(self) -> int:
        """Resend overdue deltas; returns how many were resent."""
        return sum(lane.publisher.poll() for lane in self.lanes.values())

    def wait_acked(self, timeout_s: float) -> bool:
        """Block until every delta of every shard is acknowledged (resending meanwhile); False on timeout."""
        deadline = time.monotonic() + timeout_s
        for lane in self.lanes.values():
            if not lane.publisher.wait_acked(max(0.0, deadline - time.monotonic())):
                return False
        return True

    def stats(self) -> dict:
        lanes = list(self.lanes.values())
        out: dict[str, Any] = {
            "epoch": lanes[0].publisher.epoch,
            "sent": sum(x.publisher.next_seq for x in lanes),
            "acked_seq": lanes[0].publisher.acked_seq
            if len(lanes) == 1
            else sum(x.publisher.acked_seq + 1 for x in lanes) - 1,
            "unacked": self.unacked,
            "resent": sum(x.publisher.resent for x in lanes),
            "acks": sum(x.link.acks for x in lanes),
            "deferred": self.deferred,
            "resumed": self.resumed,
            "acks_ignored": sum(x.publisher.acks_ignored for x in lanes),
            "seq_conflicts": sum(len(x.publisher.conflicts) for x in lanes),
        }
        if len(lanes) > 1:
            out["shards"] = len(lanes)
            out["sent_per_shard"] = [x.publisher.next_seq for x in lanes]
        return out

    def close(self) -> None:
        closers: list[Any] = [lane.link.close for lane in self.lanes.values()]
        closers += [self.transport.close] if hasattr(self, "transport") else []
        closers.append(self._session.close)
        closers += [lane.outbox.close for lane in self.lanes.values() if lane.outbox is not None]
        for closer in closers:
            try:
                closer()
            except Exception as exc:  # closing must not hide the run's result
                log.warning("closing the scout's Zenoh link: %s", exc)

    def __enter__(self) -> ScoutPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ZenohTransport:
    """`Transport` over an open Zenoh session: one declared publisher per key, reliable, blocking."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._publishers: dict[str, Any] = {}
        self._lock = threading.Lock()

    def put(self, key: str, payload: bytes) -> None:
        with self._lock:
            pub = self._publishers.get(key)
            if pub is None:
                pub = self.session.declare_publisher(
                    key,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    reliability=zenoh.Reliability.RELIABLE,
                )
                self._publishers[key] = pub
        pub.put(payload)

    def close(self) -> None:
        with self._lock:
            for pub in self._publishers.values():
                pub.undeclare()
            self._publishers.clear()


class ScoutLink:
    """Connects a `DeltaPublisher` to the server: acks in, resend on server (re)appearance, liveliness out.

    Use as a context manager; call `publisher.poll()` regularly from the scout's own loop.
    """

    def __init__(
        self, session: zenoh.Session, publisher: DeltaPublisher, shard: int | None = None, token: bool = True
    ) -> None:
        """shard: the shard this link's publisher feeds (None: an unsharded map); token: declare the scout's
        liveliness token (one per scout, on its first link)."""
        self.session = session
        self.publisher = publisher
        self.server_up = threading.Event()
        self.acks = 0
        mid, sid = publisher.map_id, publisher.scout_id
        self._token = session.liveliness().declare_token(alive_key(mid, sid)) if token else None
        self._ack_sub = session.declare_subscriber(ack_key(mid, sid, shard), self._on_ack)
        self._alive_sub = session.liveliness().declare_subscriber(
            alive_key(mid, server_who(shard)), self._on_server, history=True
        )

    def _on_ack(self, sample: zenoh.Sample) -> None:
        try:
            ack = decode(sample.payload.to_bytes(), expected_type="ack", key=str(sample.key_expr))
        except ProtocolError as exc:
            log.warning("ignoring bad ack on %s: %s", sample.key_expr, exc)
            return
        assert isinstance(ack, Ack)
        self.acks += 1
        self.publisher.on_ack(ack)

    def _on_server(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.server_up.set()
            self.publisher.request_resend()
        else:
            self.server_up.clear()

    def close(self) -> None:
        for entity in (self._alive_sub, self._ack_sub, self._token):
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception:  # session may already be closed
                pass

    def __enter__(self) -> ScoutLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
