"""The scout's link to the map service: the only module of `scout_agent` that talks to Zenoh.

`ScoutPublisher` opens a client session to the given endpoints and wires `protocol`'s pieces together:
`DeltaPublisher` (seq numbering, unacknowledged buffer, resend) over a `ZenohTransport`, and `ScoutLink`
(acks on `psr/<map>/ack/<scout>`, resend when the server's liveliness token (re)appears, the scout's own
liveliness token `psr/<map>/alive/<scout>`). Use it as a context manager; call `poll()` from the run loop.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from protocol.publisher import DeltaPublisher, UnackedBufferFull
from protocol.session import zenoh_config
from protocol.zenoh_transport import ScoutLink, ZenohTransport
from scout_agent.outbox import SQLiteOutbox

__all__ = ["ScoutPublisher"]

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
            raise ValueError("no endpoint to connect to; give one like tcp/127.0.0.1:7447")
        box = SQLiteOutbox(outbox) if outbox is not None else None
        if resume and box is None:
            raise ValueError("--resume needs an outbox (--outbox PATH) to resume from")
        old = box.pending() if box is not None else {}
        if old and not resume:
            n = sum(len(v) for v in old.values())
            box.close()  # type: ignore[union-attr]
            raise ValueError(
                f"outbox {outbox} holds {n} unacknowledged deltas of epoch(s) {', '.join(map(str, old))} from an "
                "earlier run; give --resume to send them, or move the file away to discard them"
            )
        self.outbox = box
        self.resumed = sum(len(v) for v in old.values())
        try:
            conf = zenoh_config(list(connect), (), None if zenoh_config_file else mode, zenoh_config_file)
            self._session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ConnectionError(
                f"cannot reach the map service's router at {', '.join(connect)} ({exc}); "
                "is `psrmap router --listen ...` (or `psrmap server --listen ...`) running there?"
            ) from None
        self.transport = ZenohTransport(self._session)
        self.publisher = DeltaPublisher(
            self.transport, map_id, scout_id, res, max_unacked=max_unacked, resend_after_s=resend_after_s,
            outbox=box, resume=old,
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
