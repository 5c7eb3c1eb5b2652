"""Remove one scout's (or one epoch's) contributions from a map's store, exactly, and record that it was done.

Sums can be subtracted, but a min or max cannot: the only exact way is to recompute every affected cell from the
contributions that remain. So the store keeps every accepted delta (`MapStore(keep_deltas=True)`, the default:
a snapshot only moves the replay cut) and the removal is:

1. the deltas to remove: `scout` (all its epochs, or only `epoch`), or `epoch` of every scout;
2. the tiles (layer, tx, ty) their cells touch;
3. those tiles rebuilt from scratch: every other delta of the log, in log order, merged with the map's own merge
   (`TiledMap.merge_columns`) for its cells in those tiles only — the same tiles a merge of the remaining deltas
   gives, every statistic (min/max included);
4. one transaction: the rebuilt tiles written (stamped with the last log id: they hold every remaining delta),
   tiles left empty deleted, the removed deltas deleted from the log, and a row in `removals` (when, whom,
   how many deltas and tiles, by which user). The seq bookkeeping stays: a resend of a removed delta is a
   duplicate, it does not come back.

It runs on the database file of a stopped server (`psrmap remove --db FILE …`): a running server holds an
exclusive lock on `FILE.lock` (`hold_lock`) and the removal refuses while it is held; access to the file is
the operator's (the command needs no network and no credential anyone else has). A sharded map: run it on
each shard's file. A store whose log was ever truncated (`--discard-deltas`) cannot be recomputed: refused.
"""

from __future__ import annotations

import fcntl
import getpass
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from map_server.decode import DeltaDecoder
from map_server.errors import MapServerError
from protocol.layers import pack_pair
from protocol.messages import CellDelta
from psrmap_mapcore import TiledMap

__all__ = ["RemovalError", "RemovalSummary", "hold_lock", "remove_contributions"]

_CHUNK = 512  # deltas decoded at a time


class RemovalError(MapServerError):
    """A removal that cannot be done (a server holds the file, the log is incomplete, nothing matches)."""


@dataclass(frozen=True)
class RemovalSummary:
    db: str
    scout: str | None
    epoch: int | None
    deltas_removed: int
    tiles_rewritten: int  # (layer, tile) rows rebuilt from the remaining deltas
    tiles_emptied: int  # (layer, tile) rows no remaining delta touches: deleted
    deltas_kept: int
    by_user: str
    at_unix: float

    def to_json(self) -> dict[str, object]:
        return dict(self.__dict__)


def hold_lock(db: str) -> IO[str]:
    """An exclusive lock on `db`.lock for as long as the returned file stays open (a running server holds it);
    RemovalError when another process holds it."""
    f = open(f"{db}.lock", "a")  # noqa: SIM115 (the lock lives as long as the file stays open)
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.close()
        raise RemovalError(
            f"{db} is in use by a running map server ({db}.lock is held): stop it first"
        ) from None
    return f


def _tile_keys(tiled: TiledMap, name: str, ix: np.ndarray, iy: np.ndarray) -> set[tuple[str, int, int]]:
    sh = tiled.shift
    t = np.unique(np.stack([np.asarray(ix, np.int64) >> sh, np.asarray(iy, np.int64) >> sh]), axis=1)
    return {(name, int(tx), int(ty)) for tx, ty in t.T.tolist()}


def remove_contributions(
    db: str | Path, scout: str | None = None, epoch: int | None = None, *, by_user: str | None = None
) -> RemovalSummary:
    """Remove the deltas of `scout` (every epoch, or only `epoch`) — or of `epoch` of every scout when `scout`
    is None — from the map in `db`, recomputing the tiles they touched from the rest; see the module doc."""
    if scout is None and epoch is None:
        raise RemovalError("name what to remove: a scout, an epoch, or both")
    db = str(db)
    if not os.path.exists(db):
        raise RemovalError(f"{db}: no such map database")
    user = by_user or getpass.getuser()
    with hold_lock(db):
        con = sqlite3.connect(db, isolation_level=None)
        try:
            return _remove(con, db, scout, epoch, user)
        finally:
            con.close()


def _remove(
    con: sqlite3.Connection, db: str, scout: str | None, epoch: int | None, user: str
) -> RemovalSummary:
    meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
    if "map" not in meta:
        raise RemovalError(f"{db} is not a map database (no map in its meta table)")
    truncated = int(meta.get("log_truncated", "0"))
    if truncated:
        raise RemovalError(
            f"{db}: its log was truncated up to delta {truncated} (a server ran with --discard-deltas), so the "
            "remaining contributions cannot be recomputed: exact removal is impossible"
        )
    res, tile = float(meta["res"]), int(meta["tile"])
    where: list[str] = []
    args: list[object] = []
    if scout is not None:
        where.append("scout = ?")
        args.append(scout)
    if epoch is not None:
        where.append("epoch = ?")
        args.append(epoch)
    cond = " AND ".join(where)
    gone = [int(i) for (i,) in con.execute(f"SELECT id FROM deltas WHERE {cond}", args)]
    what = " ".join(
        x for x in (f"scout {scout}" if scout else "", f"epoch {epoch}" if epoch is not None else "") if x
    )
    if not gone:
        raise RemovalError(f"{db}: no delta of {what} in the map's log (nothing to remove)")
    decoder = DeltaDecoder(res=res, max_bytes=2**62)
    probe = TiledMap(res, tile)
    affected: set[tuple[str, int, int]] = set()
    for payloads in _chunks(con, f"SELECT payload FROM deltas WHERE {cond} ORDER BY id", args):
        batch = decoder.decode([(None, p) for p in payloads])
        for name, c in batch.columns.items():
            if c.seg.size:
                affected |= _tile_keys(probe, name, c.ix, c.iy)
    rebuilt = TiledMap(res, tile)
    sh = rebuilt.shift
    # per layer, the affected tiles as int64 keys (`pack_pair`), for a vectorised membership test
    wanted = {
        name: np.array(sorted(pack_pair(tx, ty) for n, tx, ty in affected if n == name), np.int64)
        for name in {n for n, _, _ in affected}
    }
    kept = 0
    for payloads in _chunks(con, f"SELECT payload FROM deltas WHERE NOT ({cond}) ORDER BY id", args):
        batch = decoder.decode([(None, p) for p in payloads])
        kept += sum(type(r) is CellDelta for r in batch.results)
        for name, c in batch.columns.items():
            if not c.seg.size or name not in wanted:
                continue
            key = pack_pair(c.ix.astype(np.int64) >> sh, c.iy.astype(np.int64) >> sh)
            keep = np.isin(key, wanted[name])
            if keep.any():
                rebuilt.merge_columns(name, c.ix[keep], c.iy[keep], c.vals[:, keep])
    last_id = int(meta.get("last_id", "0"))
    written = [(n, tx, ty) for n, tx, ty in sorted(affected) if (tx, ty) in rebuilt.grids[n].slots]
    emptied = sorted(affected - set(written))
    now = time.time()
    con.execute("BEGIN IMMEDIATE")
    try:
        con.executemany(
            "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?, ?)",
            ((n, tx, ty, rebuilt.tile_blob(n, tx, ty), last_id) for n, tx, ty in written),
        )
        con.executemany("DELETE FROM tiles WHERE layer = ? AND tx = ? AND ty = ?", emptied)
        con.executemany("DELETE FROM deltas WHERE id = ?", [(i,) for i in gone])
        con.execute(
            "INSERT INTO removals VALUES (?, ?, ?, ?, ?, ?)",
            (now, scout or "*", epoch, len(gone), len(affected), user),
        )
        con.execute("COMMIT")
    except BaseException:
        con.execute("ROLLBACK")
        raise
    return RemovalSummary(db, scout, epoch, len(gone), len(written), len(emptied), kept, user, now)


def _chunks(con: sqlite3.Connection, sql: str, args: list[object]) -> Iterator[list[bytes]]:
    cur = con.execute(sql, args)
    while rows := cur.fetchmany(_CHUNK):
        yield [bytes(r[0]) for r in rows]
