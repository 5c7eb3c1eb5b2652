"""SQLite (WAL) persistence: a log of accepted deltas committed with the seq bookkeeping, plus tile
snapshots that let the log be truncated.

Crash safety (`kill -9` at any instant): a batch's deltas, seq states and counters are one
transaction, and acks go out only after it commits; so an acknowledged delta is always on disk and a
delta is on disk at most once. On open, tiles are loaded and the log since the last snapshot is
replayed. `synchronous=NORMAL` in WAL mode survives process death (not power loss).
"""

from __future__ import annotations

import json
import sqlite3
from collections import Counter
from pathlib import Path

from map_server.merge import Accepted, MergeBook, Merger, SeqState
from map_server.tiles import TiledMap

__all__ = ["MapStore"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS deltas (id INTEGER PRIMARY KEY, scout TEXT, epoch INTEGER, seq INTEGER,
                                   payload BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS seqs (scout TEXT, epoch INTEGER, hw INTEGER, above TEXT,
                                 PRIMARY KEY (scout, epoch));
CREATE TABLE IF NOT EXISTS tiles (layer TEXT, tx INTEGER, ty INTEGER, data BLOB NOT NULL,
                                  PRIMARY KEY (layer, tx, ty));
"""


class MapStore:
    """One map's database. `path` may be ":memory:" (tests)."""

    def __init__(self, path: str | Path, map_id: str, res: float, tile: int) -> None:
        self.path = str(path)
        self.db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.executescript(_SCHEMA)
        want = {"map": map_id, "res": repr(float(res)), "tile": str(tile)}
        have = dict(
            self.db.execute("SELECT key, value FROM meta WHERE key IN ('map', 'res', 'tile')").fetchall()
        )
        if have:
            for k, v in want.items():
                if have.get(k) != v:
                    self.db.close()
                    raise ValueError(
                        f"{self.path} holds map={have.get('map')} res={have.get('res')} "
                        f"tile={have.get('tile')}; asked for map={map_id} res={res} tile={tile}"
                    )
        else:
            with self.db:
                self.db.execute("BEGIN")
                self.db.executemany("INSERT INTO meta VALUES (?, ?)", list(want.items()))
        self.since_snapshot = 0

    def _meta(self, key: str, default: str) -> str:
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else default

    def load(self, merger: Merger) -> int:
        """Fill `merger` (map + book) from disk; returns the number of log deltas replayed."""
        tiled, book = merger.map, merger.book
        for layer, tx, ty, data in self.db.execute("SELECT layer, tx, ty, data FROM tiles"):
            tiled.load_tile(layer, tx, ty, data)
        tiled.clear_dirty()
        for scout, epoch, hw, above in self.db.execute("SELECT scout, epoch, hw, above FROM seqs"):
            book.seqs[(scout, epoch)] = SeqState(hw, set(json.loads(above)))
        book.version = int(self._meta("version", "0"))
        book.merged = int(self._meta("merged", "0"))
        book.duplicates = int(self._meta("duplicates", "0"))
        book.rejected = Counter(json.loads(self._meta("rejected", "{}")))
        cur = self.db.execute("SELECT payload FROM deltas ORDER BY id")
        n = merger.replay(row[0] for row in cur)
        self.since_snapshot = n
        return n

    def commit(self, accepted: list[Accepted], book: MergeBook, touched: set[tuple[str, int]]) -> None:
        """Persist one ingested batch atomically (deltas, seq states, counters)."""
        db = self.db
        db.execute("BEGIN")
        try:
            db.executemany(
                "INSERT INTO deltas (scout, epoch, seq, payload) VALUES (?, ?, ?, ?)",
                [(a.delta.scout, a.delta.epoch, a.delta.seq, a.payload) for a in accepted],
            )
            db.executemany(
                "INSERT OR REPLACE INTO seqs VALUES (?, ?, ?, ?)",
                [
                    (s, e, book.seqs[(s, e)].hw, json.dumps(sorted(book.seqs[(s, e)].above)))
                    for s, e in touched
                ],
            )
            db.executemany(
                "INSERT OR REPLACE INTO meta VALUES (?, ?)",
                [
                    ("version", str(book.version)),
                    ("merged", str(book.merged)),
                    ("duplicates", str(book.duplicates)),
                    ("rejected", json.dumps(dict(book.rejected))),
                ],
            )
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        self.since_snapshot += len(accepted)

    def snapshot(self, tiled: TiledMap) -> int:
        """Write changed tiles and truncate the log they cover, atomically; returns tiles written."""
        dirty = tiled.clear_dirty()
        db = self.db
        db.execute("BEGIN")
        try:
            db.executemany(
                "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?)",
                # a generator: one tile's blob at a time, never a second copy of the whole map
                ((layer, tx, ty, tiled.tile_blob(layer, tx, ty)) for layer, tx, ty in sorted(dirty)),
            )
            db.execute("DELETE FROM deltas")
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            tiled.dirty |= dirty
            raise
        self.since_snapshot = 0
        return len(dirty)

    def log_size(self) -> int:
        return int(self.db.execute("SELECT COUNT(*) FROM deltas").fetchone()[0])

    def close(self) -> None:
        self.db.close()
