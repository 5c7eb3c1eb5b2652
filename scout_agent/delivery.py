"""Scout-side delta publishing: seq numbering, a bounded buffer of unacknowledged deltas, resend.

The transport is anything with `put(key, payload)` (`Transport`); the Zenoh one lives in
`scout_agent.publisher`. Thread-safe: acks arrive on the network thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from protocol.codec import encode
from protocol.keys import delta_key, validate_id
from protocol.messages import Ack, CellDelta
from scout_agent.errors import ScoutConfigError, ScoutError

log = logging.getLogger(__name__)

__all__ = ["DeltaPublisher", "Outbox", "Transport", "UnackedBufferFull", "new_epoch"]


class Transport(Protocol):
    def put(self, key: str, payload: bytes) -> None: ...


class Outbox(Protocol):
    """Where a publisher keeps every delta until it is acknowledged, so a crash loses nothing
    (`scout_agent.outbox.SQLiteOutbox`). `store` must be durable when it returns."""

    def store(self, epoch: int, seq: int, payload: bytes) -> None: ...

    def release(self, epoch: int, upto_seq: int) -> None: ...

    def pending(self) -> dict[int, list[tuple[int, bytes]]]: ...


class UnackedBufferFull(ScoutError, RuntimeError):
    """`send` was called while `max_unacked` deltas await an ack; keep accumulating and retry later."""


def new_epoch() -> int:
    """A fresh epoch for a scout process start: microseconds since the Unix epoch (unique, growing)."""
    return time.time_ns() // 1000


@dataclass
class _Pending:
    payload: bytes
    sent_at: float  # clock time of the latest (re)send [s]


class DeltaPublisher:
    """Builds `CellDelta`s, numbers them 0, 1, 2, ... within one epoch, resends until acknowledged.

    max_unacked: deltas kept awaiting an ack (then `send` raises UnackedBufferFull, `full` is True);
    resend_after_s: a delta with no ack after this long is sent again by `poll`.
    """

    def __init__(
        self,
        transport: Transport,
        map_id: str,
        scout_id: str,
        res: float,
        *,
        epoch: int | None = None,
        max_unacked: int = 512,
        resend_after_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        outbox: Outbox | None = None,
        resume: Mapping[int, list[tuple[int, bytes]]] | None = None,
        shard: int | None = None,
    ) -> None:
        """outbox: persists each delta before it is sent, forgets it when acked. resume: unacknowledged
        deltas of earlier epochs (an outbox's `pending()` after a crash), resent under their original epoch
        and seq until acked; this publisher's own deltas go under a new epoch."""
        if max_unacked < 1:
            raise ScoutConfigError(f"max_unacked={max_unacked}; need >= 1")
        if not res > 0:
            raise ScoutConfigError(f"res={res}; need a cell size > 0 [m]")
        self.transport = transport
        self.map_id = validate_id(map_id, "map")
        self.scout_id = validate_id(scout_id, "scout")
        self.res = float(res)
        self.epoch = new_epoch() if epoch is None else int(epoch)
        self.max_unacked = max_unacked
        self.resend_after_s = resend_after_s
        self.clock = clock
        self.shard = shard  # the shard of a sharded map this stream feeds (None: unsharded)
        self.key = delta_key(map_id, scout_id, shard)
        self.next_seq = 0
        self.acked_seq = -1  # highest seq acknowledged (cumulative)
        self.resent = 0
        self.acks_ignored = 0  # acks for seqs this publisher never sent (forged or foreign): ignored
        self.conflicts: list[int] = []  # seqs the server rejected as merged before with other content
        self._pending: OrderedDict[int, _Pending] = OrderedDict()
        self.outbox = outbox
        now = clock()
        # earlier epochs' unacked deltas: epoch -> seq -> pending (sent_at in the past: resent at once)
        self._old: dict[int, OrderedDict[int, _Pending]] = {
            int(e): OrderedDict((int(q), _Pending(p, now - resend_after_s)) for q, p in sorted(rows))
            for e, rows in (resume or {}).items()
            if rows
        }
        if self.epoch in self._old:
            raise ScoutConfigError(
                f"epoch {self.epoch} has unacknowledged deltas to resume; a new epoch is needed"
            )
        self._lock = threading.Lock()
        self._resend_cutoff: float | None = None  # resend all sent at or before this clock time

    @property
    def unacked(self) -> int:
        """Number of deltas sent but not yet acknowledged (resumed ones of earlier epochs included)."""
        return len(self._pending) + sum(len(p) for p in self._old.values())

    @property
    def full(self) -> bool:
        return len(self._pending) >= self.max_unacked

    def build(self, layers: Mapping[str, Mapping[str, np.ndarray]], t: float, seq: int) -> CellDelta:
        clean = {}
        for name, cells in layers.items():
            clean[name] = {
                k: np.asarray(v, dtype=np.int32 if k in ("ix", "iy") else np.float64)
                for k, v in cells.items()
            }
        return CellDelta(self.map_id, self.scout_id, self.epoch, seq, float(t), self.res, clean)

    def send(self, layers: Mapping[str, Mapping[str, np.ndarray]], t: float) -> int:
        """Publish the statistics gathered since the previous delta; returns its seq."""
        with self._lock:
            if len(self._pending) >= self.max_unacked:
                raise UnackedBufferFull(
                    f"{len(self._pending)} deltas await an ack (max_unacked="
                    f"{self.max_unacked}); keep accumulating and retry after acks"
                )
            seq = self.next_seq
            payload = encode(self.build(layers, t, seq))
            if self.outbox is not None:
                self.outbox.store(self.epoch, seq, payload)  # durable before it leaves
            self.next_seq += 1
            self._pending[seq] = _Pending(payload, self.clock())
        self.transport.put(self.key, payload)
        return seq

    def on_ack(self, ack: Ack) -> int:
        """Forget every delta up to `ack.seq` of our epoch; returns how many were released.

        An ack beyond the highest seq sent cannot come from the server (it only acks what it merged): it is
        ignored and counted, so a forged ack cannot make the scout drop unacknowledged deltas. Seqs the
        server names as conflicts were not merged (other content holds that seq): logged and kept in
        `conflicts`."""
        if ack.scout != self.scout_id or ack.map != self.map_id:
            return 0
        if ack.epoch != self.epoch:
            return self._on_old_ack(ack)
        if ack.seq >= self.next_seq or any(c >= self.next_seq for c in ack.conflicts):
            self.acks_ignored += 1
            log.warning(
                "ignored an ack for seq %d of epoch %d: only seqs < %d were sent",
                ack.seq,
                ack.epoch,
                self.next_seq,
            )
            return 0
        if ack.conflicts:
            self.conflicts.extend(ack.conflicts)
            log.error(
                "server rejected seqs %s of epoch %d as seq_conflict: other content was merged under "
                "them (was this epoch reused after a restart?)",
                list(ack.conflicts),
                ack.epoch,
            )
        released = 0
        with self._lock:
            self.acked_seq = max(self.acked_seq, ack.seq)
            while self._pending:
                seq = next(iter(self._pending))
                if seq > ack.seq:
                    break
                del self._pending[seq]
                released += 1
        if released and self.outbox is not None:
            self.outbox.release(self.epoch, ack.seq)
        return released

    def _on_old_ack(self, ack: Ack) -> int:
        """An ack for a resumed earlier epoch."""
        with self._lock:
            old = self._old.get(ack.epoch)
            if not old:
                return 0
            if ack.seq > max(old) or any(c > max(old) for c in ack.conflicts):
                self.acks_ignored += 1
                return 0
            if ack.conflicts:
                self.conflicts.extend(ack.conflicts)
                log.error(
                    "server rejected resumed seqs %s of epoch %d as seq_conflict",
                    list(ack.conflicts),
                    ack.epoch,
                )
            gone = [q for q in old if q <= ack.seq]
            for q in gone:
                del old[q]
            if not old:
                del self._old[ack.epoch]
        if gone and self.outbox is not None:
            self.outbox.release(ack.epoch, ack.seq)
        return len(gone)

    def _due(self, now: float, force: bool, cutoff: float | None = None) -> list[tuple[int, bytes]]:
        with self._lock:
            due = []
            for pending in (*self._old.values(), self._pending):  # resumed epochs first, in seq order
                for seq, p in pending.items():
                    if (
                        force
                        or now - p.sent_at >= self.resend_after_s
                        or (cutoff is not None and p.sent_at <= cutoff)
                    ):
                        p.sent_at = now
                        due.append((seq, p.payload))
            return due

    def request_resend(self) -> None:
        """Ask the next `poll` to resend every delta sent until now and still unacked (safe from a
        network callback thread; deltas sent later are not affected)."""
        self._resend_cutoff = self.clock()

    def poll(self, now: float | None = None) -> int:
        """Resend (in seq order) every unacked delta whose ack is overdue, or all of them after
        `request_resend`; returns how many."""
        cutoff, self._resend_cutoff = self._resend_cutoff, None
        due = self._due(self.clock() if now is None else now, force=False, cutoff=cutoff)
        for _, payload in due:
            self.transport.put(self.key, payload)
        self.resent += len(due)
        return len(due)

    def resend_all(self) -> int:
        """Resend every unacked delta now (e.g. the server came back); returns how many."""
        due = self._due(self.clock(), force=True)
        for _, payload in due:
            self.transport.put(self.key, payload)
        self.resent += len(due)
        return len(due)

    def wait_acked(self, timeout_s: float, step_s: float = 0.05) -> bool:
        """Block until every delta is acknowledged (polling resends meanwhile); False on timeout."""
        deadline = self.clock() + timeout_s
        done = threading.Event()
        while self.unacked:
            if self.clock() > deadline:
                return False
            self.poll()
            done.wait(step_s)
        return True
