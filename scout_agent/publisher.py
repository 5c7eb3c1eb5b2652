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
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common.session import zenoh_config
from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import ack_key, alive_key
from protocol.messages import Ack
from scout_agent.delivery import DeltaPublisher, UnackedBufferFull
from scout_agent.errors import ScoutConfigError, ScoutLinkError
from scout_agent.outbox import SQLiteOutbox

__all__ = ["ScoutLink", "ScoutPublisher", "ZenohTransport"]

log = logging.getLogger(__name__)


class ScoutPublisher:
    """Publishes a scout's cell deltas to map `map_id` over Zenoh, with acks and resend."""

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
    ) -> None:
        """outbox: SQLite file where each delta is kept until acknowledged (None: memory only). resume: resend
        what the outbox holds from an earlier run under its original epoch first; without it, an outbox that
        still holds deltas is refused (they would be silently abandoned)."""
        import zenoh

        if not connect:
            raise ScoutConfigError("no endpoint to connect to; give one like tcp/127.0.0.1:7447")
        box = SQLiteOutbox(outbox) if outbox is not None else None
        if resume and box is None:
            raise ScoutConfigError("--resume needs an outbox (--outbox PATH) to resume from")
        old = box.pending() if box is not None else {}
        if old and not resume:
            n = sum(len(v) for v in old.values())
            box.close()  # type: ignore[union-attr]
            raise ScoutConfigError(
                f"outbox {outbox} holds {n} unacknowledged deltas of epoch(s) {', '.join(map(str, old))} from an "
                "earlier run; give --resume to send them, or move the file away to discard them"
            )
        self.outbox = box
        self.resumed = sum(len(v) for v in old.values())
        try:
            conf = zenoh_config(list(connect), (), None if zenoh_config_file else mode, zenoh_config_file)
            self._session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ScoutLinkError(
                f"cannot reach the map service's router at {', '.join(connect)} ({exc}); "
                "is `psrmap router --listen ...` (or `psrmap server --listen ...`) running there?"
            ) from None
        self.transport = ZenohTransport(self._session)
        self.publisher = DeltaPublisher(
            self.transport,
            map_id,
            scout_id,
            res,
            max_unacked=max_unacked,
            resend_after_s=resend_after_s,
            outbox=box,
            resume=old,
        )
        if old:
            log.info("resuming %d unacknowledged deltas of epoch(s) %s", self.resumed, list(old))
            self.publisher.resend_all()
        self.link = ScoutLink(self._session, self.publisher)
        self.deferred = 0  # sends refused because the unacknowledged buffer was full

    @property
    def unacked(self) -> int:
        return self.publisher.unacked

    @property
    def full(self) -> bool:
        return self.publisher.full

    def send(self, layers: Mapping[str, Mapping[str, np.ndarray]], t: float) -> int | None:
        """Publish one delta; None (and nothing sent) when the unacknowledged buffer is full."""
        try:
            return self.publisher.send(layers, t)
        except UnackedBufferFull:
            self.deferred += 1
            return None

    def poll(self) -> int:
        """Resend overdue deltas; returns how many were resent."""
        return self.publisher.poll()

    def wait_acked(self, timeout_s: float) -> bool:
        """Block until every delta is acknowledged (resending meanwhile); False on timeout."""
        return self.publisher.wait_acked(timeout_s)

    def stats(self) -> dict:
        p = self.publisher
        return {
            "epoch": p.epoch,
            "sent": p.next_seq,
            "acked_seq": p.acked_seq,
            "unacked": p.unacked,
            "resent": p.resent,
            "acks": self.link.acks,
            "deferred": self.deferred,
            "resumed": self.resumed,
            "acks_ignored": p.acks_ignored,
            "seq_conflicts": len(p.conflicts),
        }

    def close(self) -> None:
        closers = [self.link.close, self.transport.close, self._session.close]
        if self.outbox is not None:
            closers.append(self.outbox.close)
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

    def __init__(self, session: zenoh.Session, publisher: DeltaPublisher) -> None:
        self.session = session
        self.publisher = publisher
        self.server_up = threading.Event()
        self.acks = 0
        mid, sid = publisher.map_id, publisher.scout_id
        self._token = session.liveliness().declare_token(alive_key(mid, sid))
        self._ack_sub = session.declare_subscriber(ack_key(mid, sid), self._on_ack)
        self._alive_sub = session.liveliness().declare_subscriber(
            alive_key(mid, "server"), self._on_server, history=True
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
            try:
                entity.undeclare()
            except Exception:  # session may already be closed
                pass

    def __enter__(self) -> ScoutLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
