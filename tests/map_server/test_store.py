from __future__ import annotations

import sqlite3

import pytest

from map_server.merge import Merger
from map_server.store import MapStore
from protocol import encode
from protocol.keys import delta_key
from protocol.testing import MAP, RES, SCOUT, broken, make_delta
from psrmap_mapcore import TiledMap


def open_map(path, keep_deltas=True):
    store = MapStore(path, MAP, RES, 8, keep_deltas=keep_deltas)
    m = Merger(TiledMap(RES, tile=8), MAP)
    store.load(m)
    return store, m


def feed(store, m, seqs, scout=SCOUT):
    deltas = [make_delta(seq=s, scout=scout, cells=((s, 1), (-s, 30), (9, 9)), seed=s) for s in seqs]
    r = m.ingest([(delta_key(MAP, scout), encode(d)) for d in deltas])
    store.commit(r.accepted, m.book, r.touched)
    return r


def test_reopen_without_snapshot_replays_the_log_exactly(tmp_path):
    db = tmp_path / "map.db"
    store, m = open_map(db)
    feed(store, m, [0, 1, 3])
    key, bad, kw = broken("wrong_res")
    r = m.ingest([(key, bad)])
    store.commit(r.accepted, m.book, r.touched)
    store.db.close()  # like kill -9: no snapshot, no clean close
    store2, m2 = open_map(db)
    assert m2.map.equals(m.map) and m2.map.cells == m.map.cells
    assert m2.book.seqs[(SCOUT, 7)].hw == 1 and m2.book.seqs[(SCOUT, 7)].above == {3}
    assert (m2.book.version, m2.book.merged, m2.book.rejected) == (3, 3, {"wrong_res": 1})
    r = feed(store2, m2, [1, 2, 3, 4])  # resends after a crash are duplicates; the gap is filled
    assert r.duplicates == 2 and r.acks[(SCOUT, 7)].seq == 4
    store2.close()


def test_snapshot_truncates_log_and_reopens_exactly(tmp_path):
    db = tmp_path / "map.db"
    store, m = open_map(db)
    feed(store, m, range(5))
    assert store.snapshot(m.map) > 0 and store.log_size() == 0
    feed(store, m, range(5, 8))
    assert store.log_size() == 3
    store.close()
    store2, m2 = open_map(db)
    assert m2.map.equals(m.map) and m2.book.version == 8
    assert sqlite3.connect(db).execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    store2.close()


def test_reopening_with_other_res_is_refused(tmp_path):
    MapStore(tmp_path / "a.db", MAP, RES, 8).close()
    with pytest.raises(ValueError, match="holds map=m1 res=0.4"):
        MapStore(tmp_path / "a.db", MAP, 0.5, 8)


def test_snapshot_in_slices_survives_a_crash_at_every_step(tmp_path):
    """Tiles written a slice at a time while deltas keep coming: a crash after any step reopens exactly."""
    db = tmp_path / "map.db"
    store, m = open_map(db)
    feed(store, m, range(6))
    store.begin_snapshot(m.map)
    steps = 0
    seq = 6
    while store.snapshotting:
        done = store.snapshot_step(m.map, max_bytes=1)  # one tile per step
        steps += 1
        feed(store, m, [seq])  # merged and logged mid-round: some stored tiles already hold it
        seq += 1
        crash = tmp_path / f"crash{steps}.db"
        src = sqlite3.connect(db)
        src.execute("PRAGMA wal_checkpoint(FULL)")
        dst = sqlite3.connect(crash)
        src.backup(dst)  # the database as a kill -9 would leave it
        src.close()
        dst.close()
        s2, m2 = open_map(crash)
        assert m2.map.equals(m.map) and m2.map.cells == m.map.cells, f"after step {steps}"
        assert m2.book.version == m.book.version
        s2.close()
        if done:
            break
    assert steps > 2 and store.log_size() == seq - 6  # the round deleted the log it covered
    store.close()
    s3, m3 = open_map(db)
    assert m3.map.equals(m.map)
    s3.close()


@pytest.mark.parametrize("keep", [True, False])
def test_log_ids_only_grow_across_truncation(tmp_path, keep):
    """A snapshot round moves the replay cut; with keep_deltas=False it deletes the log it covers as well."""
    db = tmp_path / "map.db"
    store, m = open_map(db, keep)
    feed(store, m, range(3))
    store.snapshot(m.map)
    feed(store, m, [3])
    assert store.db.execute("SELECT MIN(id) FROM deltas").fetchone()[0] == (1 if keep else 4)
    assert store.log_size() == 1 and store.log_cut == 3
    store.close()
    store2, m2 = open_map(db, keep)
    assert store2.last_id == 4 and m2.map.equals(m.map)
    store2.close()


def test_a_file_with_the_keyed_digest_table_is_migrated_and_still_tells_conflicts(tmp_path):
    db = tmp_path / "old.db"
    store, m = open_map(db)
    feed(store, m, [0, 1, 2])
    digests = store.db.execute("SELECT scout, epoch, seq, digest FROM digest_log ORDER BY seq").fetchall()
    # rewrite the file into the layout of the previous release: a keyed `digests` table, no digest_log
    store.db.executescript(
        """CREATE TABLE digests (scout TEXT, epoch INTEGER, seq INTEGER, digest INTEGER NOT NULL,
                                 PRIMARY KEY (scout, epoch, seq)) WITHOUT ROWID;
           INSERT INTO digests SELECT scout, epoch, seq, digest FROM digest_log;
           DROP TABLE digest_log;"""
    )
    store.close()
    store2, m2 = open_map(db)
    tables = {r[0] for r in store2.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert "digests" not in tables and "digest_log" in tables
    assert (
        store2.db.execute("SELECT scout, epoch, seq, digest FROM digest_log ORDER BY seq").fetchall()
        == digests
    )
    key = delta_key(MAP, SCOUT)
    same = make_delta(seq=1, scout=SCOUT, cells=((1, 1), (-1, 30), (9, 9)), seed=1)
    assert m2.ingest([(key, encode(same))]).duplicates == 1  # the digest came across: a resend
    other = make_delta(seq=1, scout=SCOUT, cells=((1, 1), (-1, 30), (9, 9)), seed=99)
    assert [r for r, _ in m2.ingest([(key, encode(other))]).rejected] == ["seq_conflict"]
    store2.close()


def test_a_batch_from_many_scouts_appends_a_few_pages_not_one_per_scout(tmp_path):
    """Write amplification: the WAL frames one commit of 40 deltas from 40 scouts adds stay a handful,
    whatever the number of scouts (the digest log is append-only; keyed, it rewrote a leaf per scout)."""
    db = tmp_path / "many.db"
    store = MapStore(db, MAP, RES, 8, auto_checkpoint=False)
    m = Merger(TiledMap(RES, tile=8), MAP)
    scouts = [f"scout{i:03d}" for i in range(400)]

    def batch(seq: int, who: list[str]) -> int:
        r = m.ingest(
            [
                (delta_key(MAP, s), encode(make_delta(seq=seq, scout=s, cells=((1, 1),), seed=seq)))
                for s in who
            ]
        )
        store.commit(r.accepted, m.book, r.touched)
        return len(r.accepted)

    for seq in range(30):  # enough rows that the digest table spans many pages
        batch(seq, scouts)
    store.checkpoint()
    store.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    before = store.db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()[1]
    assert before == 0
    assert batch(30, scouts[::10]) == 40
    frames = store.db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()[1]
    # deltas (40 small payloads), digest_log tail, seqs rows + index, meta: about a dozen 16 KiB pages
    assert frames <= 20, frames
    store.close()
