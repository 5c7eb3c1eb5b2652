"""SQLite (WAL) persistence: a log of accepted deltas committed with the seq bookkeeping, plus tile
snapshots that let the log be truncated.

Crash safety (`kill -9` at any instant): a batch's deltas, seq states and counters are one
transaction, and acks go out only after it commits; so an acknowledged delta is always on disk and a
delta is on disk at most once. `synchronous=NORMAL` in WAL mode survives process death (not power loss).

Log ids only grow (`meta.last_id`). Every stored tile carries `upto`: it holds exactly the deltas with
id <= upto (it was written after the batch that ended with that id, and before the next was merged).
On open, tiles are loaded and the log is replayed, each delta's cells only into tiles with upto < id.
That lets a snapshot be written a few tiles at a time between batches (`begin_snapshot` /
`snapshot_step`) instead of stalling the merge worker for the whole map: a round snapshots the tiles
dirty at its start, and when all are written it deletes the log up to the id it started at (every
delta up to there is then in every tile it touched).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import time
from collections import Counter
from pathlib import Path

from map_server.errors import MapServerConfigError
from map_server.merge import Accepted, MergeBook, Merger, SeqState
from psrmap_mapcore import TiledMap

log = logging.getLogger(__name__)

__all__ = ["MapStore"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS deltas (id INTEGER PRIMARY KEY, scout TEXT, epoch INTEGER, seq INTEGER,
                                   payload BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS seqs (scout TEXT, epoch INTEGER, hw INTEGER, above TEXT,
                                 PRIMARY KEY (scout, epoch));
CREATE TABLE IF NOT EXISTS tiles (layer TEXT, tx INTEGER, ty INTEGER, data BLOB NOT NULL,
                                  upto INTEGER NOT NULL DEFAULT 0, PRIMARY KEY (layer, tx, ty));
CREATE TABLE IF NOT EXISTS digest_log (scout TEXT, epoch INTEGER, seq INTEGER, digest INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS removals (at_unix REAL NOT NULL, scout TEXT NOT NULL, epoch INTEGER, deltas INTEGER NOT NULL,
                                     tiles INTEGER NOT NULL, by_user TEXT NOT NULL);
"""
# meta.log_cut: every delta with id <= log_cut is in every stored tile (a snapshot round completed); load replays
# only the log above it. meta.log_truncated: the largest id ever deleted by a snapshot round (0: the log holds
# every accepted delta since the map began, so a scout's contributions can be removed exactly).
# digest_log is append-only (rowid order; no index): a batch's digests land on the table's last page. Keyed by
# (scout, epoch, seq) as before (`digests`, a WITHOUT ROWID B-tree) every delta of a batch from many scouts
# rewrote its own leaf page: one 16 KiB WAL frame per delta. Loading reads it in order; a later row wins.


def _signed(d: int) -> int:
    """uint64 digest as SQLite's signed 64-bit INTEGER."""
    return d - (1 << 64) if d >= 1 << 63 else d


SNAPSHOT_SLICE_BYTES = 512 << 10  # tile bytes written per `snapshot_step`
# a WAL longer than this is checkpointed in RESTART mode (the writer waits for the copy, then the next commit
# starts the WAL over and `journal_size_limit` truncates the file to this size): the bound on the WAL. The
# service's checkpointer runs PASSIVE every 50 ms and this RESTART only past the limit. With PASSIVE alone every
# 0.5 s the WAL grew without bound under a sustained 2,500 deltas/s (37 GiB per shard in a 10-minute soak, until
# the disk was full); RESTART at 16–64 MiB bounded it but stalled commits often (p99 140–350 ms); at 256 MiB
# p99 was 32–93 ms per minute over 10 minutes, rising with time; at 1 GiB 22–31 ms every minute, flat
# (benchmarks/soak.py --scouts 500 --shards 2 --minutes 10: 2,500 deltas/s; the WAL reaches the limit in ~1 minute).
WAL_LIMIT_BYTES = 1 << 30
PAGE_SIZE = 16384
DELETE_SLICE = 250  # log rows deleted per `snapshot_step` (a delta's blob spans overflow pages)


class MapStore:
    """One map's database. `path` may be ":memory:" (tests)."""

    def __init__(
        self,
        path: str | Path,
        map_id: str,
        res: float,
        tile: int,
        *,
        auto_checkpoint: bool = True,
        keep_deltas: bool = True,
    ) -> None:
        """keep_deltas: a completed snapshot round only moves the replay cut (`meta.log_cut`) and every accepted
        delta stays in `deltas` (what `map_server.removal` recomputes a scout's removal from; disk grows by each
        delta's payload); False: the round deletes the log it covers (the log is then incomplete for good)."""
        self.path = str(path)
        self.keep_deltas = keep_deltas
        self.db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        # a new database only (ignored once it exists): a delta's payload (~5 KiB) fits in one page,
        # so deleting the log needs no walk of overflow chains, and a tile spans 4x fewer pages
        self.db.execute(f"PRAGMA page_size={PAGE_SIZE}")
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        if auto_checkpoint:
            self.db.execute("PRAGMA wal_autocheckpoint=1000")
        else:
            # the service checkpoints from its own thread (`checkpoint`): a commit of the merge worker
            # then never waits for a checkpoint's copy + fsync
            self.db.execute("PRAGMA wal_autocheckpoint=0")
        self.db.execute(f"PRAGMA journal_size_limit={WAL_LIMIT_BYTES}")  # the file shrinks back on a restart
        self._ckpt: sqlite3.Connection | None = None
        self.db.executescript(_SCHEMA)
        want = {"map": map_id, "res": repr(float(res)), "tile": str(tile)}
        have = dict(
            self.db.execute("SELECT key, value FROM meta WHERE key IN ('map', 'res', 'tile')").fetchall()
        )
        if have:
            for k, v in want.items():
                if have.get(k) != v:
                    self.db.close()
                    raise MapServerConfigError(
                        f"{self.path} holds map={have.get('map')} res={have.get('res')} "
                        f"tile={have.get('tile')}; asked for map={map_id} res={res} tile={tile}"
                    )
        else:
            with self.db:
                self.db.execute("BEGIN")
                self.db.executemany("INSERT INTO meta VALUES (?, ?)", list(want.items()))
        self._migrate_digests()
        cols = [r[1] for r in self.db.execute("PRAGMA table_info(tiles)")]
        if "upto" not in cols:  # a database from before per-tile watermarks: its tiles predate its log
            self.db.execute("ALTER TABLE tiles ADD COLUMN upto INTEGER NOT NULL DEFAULT 0")
        max_id = self.db.execute("SELECT COALESCE(MAX(id), 0) FROM deltas").fetchone()[0]
        self.last_id = max(int(self._meta("last_id", "0")), int(max_id))
        self.log_cut = int(self._meta("log_cut", "0"))
        self.since_snapshot = 0
        self.last_commit_unix: float | None = None
        self.last_error: str | None = (
            None  # the original error of the last failed commit (None after a good one)
        )
        self.last_error_unix: float | None = None
        self.checkpoints: Counter[str] = Counter()  # checkpoints run, by mode
        self._pending: list[tuple[str, int, int]] = []  # tiles of the snapshot round under way
        self._cut = 0  # the round deletes the log up to this id when its tiles are written

    def _migrate_digests(self) -> None:
        """A database from before the append-only digest log: move its keyed `digests` table over, once."""
        if not self.db.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'digests'"
        ).fetchone():
            return
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute(
                "INSERT INTO digest_log SELECT scout, epoch, seq, digest FROM digests ORDER BY scout, epoch, seq"
            )
            self.db.execute("DROP TABLE digests")

    def _meta(self, key: str, default: str) -> str:
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else default

    def load(self, merger: Merger) -> int:
        """Fill `merger` (map + book) from disk; returns the number of log deltas replayed."""
        tiled, book = merger.map, merger.book
        upto: dict[tuple[str, int, int], int] = {}
        for layer, tx, ty, data, up in self.db.execute("SELECT layer, tx, ty, data, upto FROM tiles"):
            tiled.load_tile(layer, tx, ty, data)
            upto[(layer, tx, ty)] = int(up)
        tiled.clear_dirty()
        for scout, epoch, hw, above in self.db.execute("SELECT scout, epoch, hw, above FROM seqs"):
            book.seqs[(scout, epoch)] = SeqState(hw, set(json.loads(above)))
        for scout, epoch, seq, digest in self.db.execute(
            "SELECT scout, epoch, seq, digest FROM digest_log ORDER BY rowid"
        ):
            st = book.seqs.get((scout, epoch))
            if st is not None:
                st.set_digest(int(seq), int(digest) % (1 << 64))
        book.version = int(self._meta("version", "0"))
        book.merged = int(self._meta("merged", "0"))
        book.duplicates = int(self._meta("duplicates", "0"))
        book.rejected = Counter(json.loads(self._meta("rejected", "{}")))
        book.scout_tiles = Counter(json.loads(self._meta("scout_tiles", "{}")))
        cur = self.db.execute("SELECT id, payload FROM deltas WHERE id > ? ORDER BY id", (self.log_cut,))
        n = merger.replay(((int(i), p) for i, p in cur), upto)
        self.since_snapshot = n
        return n

    def commit(self, accepted: list[Accepted], book: MergeBook, touched: set[tuple[str, int]]) -> None:
        """Persist one ingested batch atomically (deltas, seq states, counters)."""
        db = self.db
        db.execute("BEGIN")
        try:
            first = self.last_id + 1
            db.executemany(
                "INSERT INTO deltas (id, scout, epoch, seq, payload) VALUES (?, ?, ?, ?, ?)",
                [
                    (first + k, a.delta.scout, a.delta.epoch, a.delta.seq, a.payload)
                    for k, a in enumerate(accepted)
                ],
            )
            db.executemany(
                "INSERT INTO digest_log VALUES (?, ?, ?, ?)",
                [(a.delta.scout, a.delta.epoch, a.delta.seq, _signed(a.digest)) for a in accepted],
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
                    ("scout_tiles", json.dumps(dict(book.scout_tiles))),
                    ("last_id", str(first + len(accepted) - 1)),
                ],
            )
            db.execute("COMMIT")
        except BaseException as exc:
            self._rollback(exc)
            raise
        self.last_id = first + len(accepted) - 1
        self.since_snapshot += len(accepted)
        self.last_commit_unix = time.time()
        self.last_error = None

    def _rollback(self, exc: BaseException) -> None:
        """Roll back after `exc`, keeping `exc` as the error to report: a failing ROLLBACK (SQLite may have
        rolled back itself, e.g. on a full disk) is logged, never raised in its place."""
        self.last_error = f"{type(exc).__name__}: {exc}"
        self.last_error_unix = time.time()
        try:
            if self.db.in_transaction:
                self.db.execute("ROLLBACK")
        except sqlite3.Error as rb:
            log.error("rollback after %s failed too: %s", self.last_error, rb)

    def health(self) -> dict[str, str | float | None]:
        """`ok` or `error` (the last commit failed: its original error), and when the last commit landed."""
        return {
            "store": "error" if self.last_error else "ok",
            "store_error": self.last_error,
            "last_commit_unix": self.last_commit_unix,
        }

    def snapshot(self, tiled: TiledMap) -> int:
        """Write every changed tile and truncate the whole log, atomically; returns tiles written."""
        self.begin_snapshot(tiled)
        n = len(self._pending)
        self.snapshot_step(tiled, max_bytes=None)
        return n

    @property
    def snapshotting(self) -> bool:
        """A snapshot round is under way (call `snapshot_step` until it returns True)."""
        return bool(self._pending) or self._cut > 0

    def begin_snapshot(self, tiled: TiledMap) -> None:
        """Start a round: the tiles changed so far, then the log up to the last committed delta."""
        dirty = tiled.clear_dirty()
        self._pending = sorted(set(self._pending) | dirty)
        self._cut = self.last_id

    def snapshot_step(self, tiled: TiledMap, max_bytes: int | None = SNAPSHOT_SLICE_BYTES) -> bool:
        """Write the next tiles of the round (about `max_bytes`; None: all) in one transaction; once
        they are all written, delete the log the round covers (DELETE_SLICE rows a step). Call between
        batches (after a commit), from the thread that merges. Returns True when the round is complete."""
        db = self.db
        if not self._pending:  # tiles done: every delta up to the cut is in every tile it touched
            if self.keep_deltas:
                self._set_meta("log_cut", self._cut)
                self.log_cut = self._cut
            else:
                lo = db.execute("SELECT MIN(id) FROM deltas").fetchone()[0]
                if lo is not None and lo <= self._cut:
                    hi = self._cut if max_bytes is None else min(self._cut, lo - 1 + DELETE_SLICE)
                    db.execute("BEGIN")
                    try:
                        db.execute("DELETE FROM deltas WHERE id <= ?", (hi,))
                        db.execute("INSERT OR REPLACE INTO meta VALUES ('log_truncated', ?)", (str(hi),))
                        db.execute("COMMIT")
                    except BaseException:
                        db.execute("ROLLBACK")
                        raise
                    if hi < self._cut:
                        return False
                self._set_meta("log_cut", self._cut)
                self.log_cut = self._cut
            self.since_snapshot = self.last_id - self._cut
            self._cut = 0
            return True
        take: list[tuple[str, int, int]] = []
        size = 0
        for key in self._pending:
            if max_bytes is not None and take and size >= max_bytes:
                break
            take.append(key)
            size += tiled.grids[key[0]].store[0].nbytes
        self.write_tiles(tiled, take)  # (they leave the round's pending list)
        if not self._pending and max_bytes is None:
            return self.snapshot_step(tiled, None)
        return False

    def write_tiles(self, tiled: TiledMap, keys: list[tuple[str, int, int]]) -> None:
        """Write these (layer, tx, ty) tiles now, stamped with the last committed log id, in one transaction
        (a map bigger than memory evicts them next: map_server.paging); they leave a snapshot round under way."""
        db = self.db
        db.execute("BEGIN")
        try:
            db.executemany(
                "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?, ?)",
                # a generator: one tile's blob at a time, never a second copy of the whole map
                ((layer, tx, ty, tiled.tile_blob(layer, tx, ty), self.last_id) for layer, tx, ty in keys),
            )
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        gone = set(keys)
        self._pending = [k for k in self._pending if k not in gone]

    def checkpoint(self) -> tuple[int, int]:
        """Copy the WAL into the database from its own connection (any one thread); returns (frames in the
        WAL, frames checkpointed).

        PASSIVE (never blocks the writer) while the WAL is short; once it is longer than WAL_LIMIT_BYTES,
        RESTART: the merge worker's next commit waits for the copy (the busy timeout), then starts the WAL from
        its beginning and `journal_size_limit` truncates the file — the WAL stays bounded under any load.
        """
        if self.path == ":memory:":
            return (0, 0)
        if self._ckpt is None:
            self._ckpt = sqlite3.connect(
                self.path, check_same_thread=False, isolation_level=None, timeout=10.0
            )
            self._ckpt.execute("PRAGMA synchronous=NORMAL")
        try:
            wal = os.path.getsize(self.path + "-wal")
        except OSError:
            wal = 0
        mode = "RESTART" if wal > WAL_LIMIT_BYTES else "PASSIVE"
        _, frames, done = self._ckpt.execute(f"PRAGMA wal_checkpoint({mode})").fetchone()
        self.checkpoints[mode] += 1
        return int(frames), int(done)

    def log_size(self) -> int:
        """Deltas a reopen would replay (those above the cut)."""
        return int(self.db.execute("SELECT COUNT(*) FROM deltas WHERE id > ?", (self.log_cut,)).fetchone()[0])

    def _set_meta(self, key: str, value: object) -> None:
        self.db.execute("BEGIN")
        try:
            self.db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, str(value)))
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise

    def close(self) -> None:
        if self._ckpt is not None:
            self._ckpt.close()
            self._ckpt = None
        self.db.close()
