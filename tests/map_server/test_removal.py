"""Issue 25: an operator removes one scout's (or one epoch's) contributions exactly — every statistic, min/max
included — and the removal is recorded; the map afterwards equals a merge of the others' deltas."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest

from map_server.merge import Merger
from map_server.removal import RemovalError, hold_lock, remove_contributions
from map_server.store import MapStore
from protocol import encode
from protocol.keys import delta_key
from protocol.messages import CellDelta
from protocol.testing import MAP, RES, make_delta
from psrmap_mapcore import TiledMap

TILE = 8
LAYERS3 = ("elevation", "slip", "giim")


def _deltas() -> list[CellDelta]:
    """Three scouts (s1 in two epochs) over overlapping cells of several tiles, in arrival order."""
    rng = np.random.default_rng(5)
    out = []
    seqs: dict[tuple[str, int], int] = {}
    for k in range(60):
        scout, epoch = [("s1", 1), ("s2", 1), ("s3", 4), ("s1", 2)][k % 4]
        seq = seqs.get((scout, epoch), 0)
        seqs[(scout, epoch)] = seq + 1
        cells = {(int(x), int(y)) for x, y in rng.integers(-12, 12, (6, 2))}
        out.append(
            make_delta(seq=seq, scout=scout, epoch=epoch, cells=tuple(sorted(cells)), layers=LAYERS3, seed=k)
        )
    return out


def _sample(d: CellDelta) -> tuple[str, bytes]:
    return delta_key(MAP, d.scout), encode(d)


def _build(db, deltas: list[CellDelta], clean: bool) -> TiledMap:
    """A store fed in batches with a snapshot round in the middle; `clean`: closed with a full snapshot, else
    left as a kill -9 would (tiles lag behind the log). Returns the map the server held."""
    store = MapStore(db, MAP, RES, TILE)
    m = Merger(TiledMap(RES, tile=TILE), MAP)
    for i in range(0, len(deltas), 7):
        r = m.ingest([_sample(d) for d in deltas[i : i + 7]])
        store.commit(r.accepted, m.book, r.touched)
        if i == 21:
            store.snapshot(m.map)
    if clean:
        store.snapshot(m.map)
        store.close()
    else:
        store.db.close()
    return m.map


def _reference(deltas: list[CellDelta]) -> TiledMap:
    m = Merger(TiledMap(RES, tile=TILE), MAP)
    for d in deltas:
        m.ingest([_sample(d)])
    return m.map


def _load(db) -> Merger:
    m = Merger(TiledMap(RES, tile=TILE), MAP)
    store = MapStore(db, MAP, RES, TILE)
    store.load(m)
    store.close()
    return m


@pytest.mark.parametrize("clean", [True, False])
@pytest.mark.parametrize("who", [("s1", None), ("s1", 1), ("s3", None), (None, 1)])
def test_removal_leaves_exactly_a_merge_of_the_others(tmp_path, clean, who):
    scout, epoch = who
    deltas = _deltas()
    db = tmp_path / "m.db"
    held = _build(db, deltas, clean)
    removed = [
        d for d in deltas if (scout is None or d.scout == scout) and (epoch is None or d.epoch == epoch)
    ]
    others = [d for d in deltas if d not in removed]
    want = _reference(others)
    assert not held.equals(want)  # the removed deltas were in the map
    summary = remove_contributions(db, scout, epoch, by_user="operator")
    assert summary.deltas_removed == len(removed) and summary.deltas_kept == len(others)
    got = _load(db)
    assert got.map.equals(want)  # every statistic of every layer, min/max included
    for layer in LAYERS3:  # and as a reader sees it
        a = got.map.region(-12, -12, 12, 12, (layer,), ("all",))[layer]
        b = want.region(-12, -12, 12, 12, (layer,), ("all",))[layer]
        for s in a:
            np.testing.assert_array_equal(a[s], b[s])
    rows = sqlite3.connect(db).execute("SELECT scout, epoch, deltas, by_user FROM removals").fetchall()
    assert rows == [(scout or "*", epoch, len(removed), "operator")]
    # the seq bookkeeping stays: a resend of a removed delta is a duplicate, it does not come back
    r = got.ingest([_sample(removed[0])])
    assert r.duplicates == 1 and not r.accepted


def test_removal_is_refused_while_a_server_holds_the_file_or_when_the_log_is_incomplete(tmp_path):
    deltas = _deltas()
    db = tmp_path / "m.db"
    _build(db, deltas, clean=True)
    with hold_lock(str(db)), pytest.raises(RemovalError, match="running map server"):
        remove_contributions(db, "s1")
    with pytest.raises(RemovalError, match="no delta of scout nobody"):
        remove_contributions(db, "nobody")
    lossy = tmp_path / "lossy.db"
    store = MapStore(lossy, MAP, RES, TILE, keep_deltas=False)
    m = Merger(TiledMap(RES, tile=TILE), MAP)
    r = m.ingest([_sample(d) for d in deltas[:10]])
    store.commit(r.accepted, m.book, r.touched)
    store.snapshot(m.map)
    store.close()
    with pytest.raises(RemovalError, match="truncated"):
        remove_contributions(lossy, "s1")


def test_psrmap_remove_on_a_running_servers_file_says_stop_it_then_removes(tmp_path, router, capsys):
    from map_server.cli import main
    from map_server.service import MapService, ServerConfig

    db = str(tmp_path / "live.db")
    cfg = ServerConfig(map_id=MAP, res=RES, tile=TILE, db=db, connect=(router,))
    with MapService(cfg) as service:
        r = service.merger.ingest([_sample(d) for d in _deltas()[:8]])  # (as the worker would, without Zenoh)
        service.store.commit(r.accepted, service.merger.book, r.touched)  # type: ignore[union-attr]
        assert main(["remove", "--db", db, "--scout", "s2"]) == 1
        assert "stop it first" in capsys.readouterr().err
    assert main(["remove", "--db", db, "--scout", "s2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["deltas_removed"] == 2 and out["scout"] == "s2"
    want = _reference([d for d in _deltas()[:8] if d.scout != "s2"])
    assert _load(db).map.equals(want)
