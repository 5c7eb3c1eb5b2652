"""The scout's persistent outbox: every delta is written to SQLite before it is sent and deleted once the server
acknowledges it, so a scout killed with unacknowledged deltas (server down, link cut) loses none of them:
`psrmap scout --resume` resends them under their original epoch, then continues under a new one."""

from __future__ import annotations

import os
import sqlite3
import threading
from pathlib import Path

__all__ = ["SQLiteOutbox", "default_outbox_path"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS pending (epoch INTEGER, seq INTEGER, payload BLOB NOT NULL,
                                    PRIMARY KEY (epoch, seq)) WITHOUT ROWID;
"""


def default_outbox_path(map_id: str, scout_id: str) -> Path:
    """`$XDG_STATE_HOME/psrmap/outbox-<map>-<scout>.db` (default `~/.local/state/...`)."""
    base = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    return base / "psrmap" / f"outbox-{map_id}-{scout_id}.db"


class SQLiteOutbox:
    """`scout_agent.delivery.Outbox` in one SQLite file (WAL, synchronous=FULL: a stored delta survives a crash of
    the process and of the machine). Thread-safe: acks arrive on the network thread."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

        self._lock = threading.Lock()
        self.db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(_SCHEMA)

    def store(self, epoch: int, seq: int, payload: bytes) -> None:
        with self._lock:
            self.db.execute("INSERT OR REPLACE INTO pending VALUES (?, ?, ?)", (epoch, seq, payload))

    def release(self, epoch: int, upto_seq: int) -> None:
        with self._lock:
            self.db.execute("DELETE FROM pending WHERE epoch = ? AND seq <= ?", (epoch, upto_seq))

    def pending(self) -> dict[int, list[tuple[int, bytes]]]:
        out: dict[int, list[tuple[int, bytes]]] = {}
        with self._lock:
            for epoch, seq, payload in self.db.execute(
                "SELECT epoch, seq, payload FROM pending ORDER BY epoch, seq"
            ):
                out.setdefault(int(epoch), []).append((int(seq), bytes(payload)))
        return out

    def close(self) -> None:
        with self._lock:
            self.db.close()
