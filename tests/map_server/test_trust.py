"""Issue 12's findings, each reproduced: a reused seq with other content, a forged ack, a store that refuses
writes (disk full), an unexpected error in the merge worker — none may fail silently or lose a measurement."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import InMemoryTransport, wait_until

from map_server.merge import Merger
from map_server.store import MapStore
from protocol import decode, encode
from protocol.keys import delta_key, status_key
from protocol.messages import Ack, Status
from protocol.testing import MAP, RES, SCOUT, make_delta
from psrmap_mapcore import TiledMap
from scout_agent.delivery import DeltaPublisher
from scout_agent.publisher import ScoutLink, ZenohTransport

KEY = delta_key(MAP, SCOUT)


def _merger() -> Merger:
    return Merger(TiledMap(RES), MAP)


def test_same_seq_with_other_content_is_a_conflict_named_in_the_ack(tmp_path):
    store = MapStore(tmp_path / "m.db", MAP, RES, 64)
    m = _merger()
    first = encode(make_delta(seq=0, seed=1))
    res = m.ingest([(KEY, first)])
    store.commit(res.accepted, m.book, res.touched)
    again = m.ingest([(KEY, first)])  # the same delta resent: a duplicate
    assert again.duplicates == 1 and not again.rejected
    other = encode(make_delta(seq=0, seed=2))  # a scout restarted with its old epoch: other content
    res = m.ingest([(KEY, other)])
    assert res.duplicates == 0 and [r for r, _ in res.rejected] == ["seq_conflict"]
    ack = next(iter(res.acks.values()))
    assert ack.conflicts == (0,)
    assert m.book.rejected["seq_conflict"] == 1
    assert decode(encode(ack)).conflicts == (0,)  # the contract carries it to the scout
    # the digests survive a restart: a reopened server still tells a conflict from a duplicate
    store.close()
    m2 = _merger()
    MapStore(tmp_path / "m.db", MAP, RES, 64).load(m2)
    assert m2.ingest([(KEY, first)]).duplicates == 1
    assert [r for r, _ in m2.ingest([(KEY, other)]).rejected] == ["seq_conflict"]


def test_a_forged_ack_cannot_make_a_scout_drop_its_unacked_deltas():
    pub = DeltaPublisher(InMemoryTransport(), MAP, "s1", RES, epoch=5)
    for i in range(20):
        d = make_delta(seq=i, scout="s1")
        pub.send(d.layers, d.t)
    assert pub.on_ack(Ack(MAP, "s1", 5, 10**12)) == 0  # beyond anything sent: ignored
    assert pub.unacked == 20 and pub.acks_ignored == 1
    assert pub.on_ack(Ack(MAP, "s1", 5, 4)) == 5  # a real one still works
    assert pub.on_ack(Ack(MAP, "s1", 5, 9, conflicts=(7,))) == 5
    assert pub.conflicts == [7]


def _status(client) -> Status:
    replies = list(client.get(status_key(MAP), timeout=5))
    st = decode(replies[0].ok.payload.to_bytes())
    assert isinstance(st, Status)
    return st


def test_a_full_disk_is_reported_and_the_service_recovers_without_restart(served_map):
    with served_map(MAP, RES) as (service, client):
        pub = DeltaPublisher(ZenohTransport(client), MAP, "s1", RES, resend_after_s=0.5)
        with ScoutLink(client, pub) as link:
            assert link.server_up.wait(5)
            sent = []
            for i in range(5):
                d = make_delta(seq=i, scout="s1", cells=((i, 0),), layers=("slip",), seed=i)
                pub.send(d.layers, d.t)
                sent.append(d)
            assert pub.wait_acked(10)
            with service.lock:  # the disk is full: SQLite may not grow the file by a single page
                pages = service.store.db.execute("PRAGMA page_count").fetchone()[0]
                service.store.db.execute(f"PRAGMA max_page_count={pages}")
            for i in range(5, 60):
                d = make_delta(
                    seq=i, scout="s1", cells=tuple((i, k) for k in range(40)), layers=("slip",), seed=i
                )
                pub.send(d.layers, d.t)
                sent.append(d)
            assert wait_until(lambda: _status(client).health.get("store") == "error", 15.0)
            st = _status(client)
            assert "full" in str(st.health["store_error"]) and st.health["worker"] == "waiting_for_store"
            assert pub.unacked > 0  # nothing uncommitted is acked
            committed = service.store.last_id
            assert (
                service.merger.book.merged - committed <= service.config.batch_max
            )  # at most one batch ahead
            with service.lock:  # space again
                service.store.db.execute("PRAGMA max_page_count=1073741823")
            assert pub.wait_acked(20)
            st = _status(client)
            assert st.health["store"] == "ok" and st.health["worker"] == "ok" and st.merged == 60
            want = sum(float(d.layers["slip"]["n"].sum()) for d in sent)
            assert service.map.totals()["slip"]["n"] == want


def test_an_unexpected_error_in_the_merge_worker_is_counted_and_reported(served_map, monkeypatch):
    with served_map(MAP, RES) as (service, client):

        def broken_apply(*a, **k):
            raise RuntimeError("injected bug")

        monkeypatch.setattr(service.merger, "apply", broken_apply)
        client.put(f"psr/{MAP}/delta/s1", encode(make_delta(seq=0, scout="s1")))
        assert service.failed.wait(10)
        st = _status(client)  # the query side keeps answering
        assert st.health["worker"] == "failed" and "injected bug" in str(st.health["worker_error"])
        assert st.rejected.get("internal_RuntimeError") == 1
        assert np.isfinite(st.version)


def test_status_health_round_trips_and_rejects_garbage():
    st = Status(
        MAP,
        RES,
        1,
        2,
        3,
        0,
        {},
        {},
        {"worker": "ok", "store": "ok", "last_commit_unix": 1.5, "store_error": None},
    )
    assert decode(encode(st)).health == st.health
    import msgpack

    from protocol.errors import ProtocolError

    body = msgpack.unpackb(encode(st))
    body["health"] = {"worker": [1, 2]}
    with pytest.raises(ProtocolError, match="health"):
        decode(msgpack.packb(body))


def test_cells_spread_over_far_tiles_cannot_blow_up_memory():
    """Issue 12: 200 small deltas with cells spread over ±10⁶ cells allocated +609 MiB (a 64×64 tile per cell)."""
    from map_server.limits import Limits

    rng = np.random.default_rng(0)
    m = Merger(TiledMap(RES), MAP, limits=Limits(max_new_tiles_per_delta=4, max_tiles=64))
    for seq in range(200):
        ix, iy = rng.integers(-(10**6), 10**6, 12), rng.integers(-(10**6), 10**6, 12)
        d = make_delta(seq=seq, cells=tuple(zip(ix.tolist(), iy.tolist(), strict=True)), layers=("slip",))
        m.ingest([(KEY, encode(d))])
    assert m.book.rejected["limit_new_tiles"] == 200 and len(m.map.gslots) == 0
    few = make_delta(seq=200, cells=((5_000, 5_000), (-9_000, 3)), layers=("slip",))  # 2 new tiles: allowed
    assert len(m.ingest([(KEY, encode(few))]).accepted) == 1 and len(m.map.gslots) == 2


def test_a_burst_of_huge_messages_is_dropped_before_the_server_copies_it(served_map):
    """Issue 12: 50 queued 50 MB messages cost 2.6 GiB because they were copied before the size check. Now Zenoh
    drops a message far over the limit itself, and the worker checks the size before copying the rest."""
    with served_map(MAP, RES) as (service, client):
        big = b"\x00" * (20 << 20)
        for _ in range(5):
            client.put(KEY, big)
        # a message far over the limit may cost the link it came on (Zenoh drops it and the transport is
        # re-established), so the next delta is resent until merged, as a scout's outbox resends unacked
        # deltas: the server must keep serving, and merge it exactly once however often it arrives
        good = encode(make_delta(seq=0))

        def resent_until_merged() -> bool:
            if service.merger.book.merged == 0:
                client.put(KEY, good)
            return service.merger.book.merged == 1

        assert wait_until(resent_until_merged, timeout_s=60)
        assert _status(client).health["worker"] == "ok" and service.merger.book.merged == 1
