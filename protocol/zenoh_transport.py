"""The Zenoh side of `DeltaPublisher` (the one module of `protocol` that imports zenoh).

`ZenohTransport` puts deltas reliably with blocking congestion control; `ScoutLink` wires a
publisher to its acks, re-sends when the server's liveliness token (re)appears, and holds the
scout's own liveliness token.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import zenoh

from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import ack_key, alive_key
from protocol.messages import Ack
from protocol.publisher import DeltaPublisher

__all__ = ["ScoutLink", "ZenohTransport"]

log = logging.getLogger(__name__)


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
