"""A map split over two shard servers on a real router: scouts discover the partition, split their deltas,
each shard merges exactly its own tiles; queries fan out and stitch to what one server would hold; status
aggregates; a misrouted delta is rejected; planners are told which tiles changed."""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh
from helpers import TILE, plannable_delta, spawn, wait_line, walk

from consumer_planner.client import ClientConfig, RegionWatch, query_region
from map_server.merge import Merger
from map_server.service import MapService, ServerConfig
from protocol import encode
from protocol.keys import delta_key
from protocol.partition import Partition
from protocol.testing import MAP, RES, make_delta
from psrmap_common.query import aggregate_status, get_partition, get_status, get_statuses, wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_mapcore import TiledMap
from scout_agent.publisher import ScoutPublisher


@contextlib.contextmanager
def shards(router: str, tmp_path, k: int = 2) -> Iterator[tuple[list[MapService], zenoh.Session]]:
    cfgs = [
        ServerConfig(map_id=MAP, res=RES, tile=TILE, db=str(tmp_path / f"s{i}.db"), connect=(router,), shards=k, shard=i)
        for i in range(k)
    ]  # fmt: skip
    with contextlib.ExitStack() as stack:
        services = [stack.enter_context(MapService(c)) for c in cfgs]
        client = stack.enter_context(zenoh.open(zenoh_config(connect=[router], mode="client")))
        for i in range(k):
            assert wait_for_server(client, MAP, shard=i)
        yield services, client


def test_partition_is_deterministic_and_splits_every_cell_once():
    p = Partition(4, 8)
    rng = np.random.default_rng(0)
    ix, iy = rng.integers(-500, 500, 2000), rng.integers(-500, 500, 2000)
    s = p.shard_of(ix, iy)
    assert set(np.unique(s).tolist()) == {0, 1, 2, 3}  # a hash: every shard gets cells
    assert (s == p.shard_of(ix, iy)).all()
    same_tile = p.shard_of(ix - np.mod(ix, 8), iy - np.mod(iy, 8))
    assert (s == same_tile).all()  # a tile belongs to one shard
    layers = {"slip": {"ix": ix, "iy": iy, "n": np.ones(ix.size)}}
    parts = p.split(layers)
    assert sum(part["slip"]["ix"].size for part in parts.values()) == ix.size
    for k, part in parts.items():
        assert (p.shard_of(part["slip"]["ix"], part["slip"]["iy"]) == k).all()
    with pytest.raises(ValueError, match="power of two"):
        Partition(2, 12)
    with pytest.raises(ValueError, match="1..1024"):
        Partition(0, 8)


def test_two_shards_hold_what_one_server_would(router, tmp_path):
    deltas = walk(40)
    ref = Merger(TiledMap(RES, TILE), MAP)  # one unsharded server's merge of the same deltas
    with (
        shards(router, tmp_path) as (services, client),
        RegionWatch(client, MAP, RES, (0.0, 0.0, 40.0, 4.0)) as watch,
    ):
        assert get_partition(client, MAP) == Partition(2, TILE)
        with ScoutPublisher(MAP, "s1", RES, [router], outbox=None) as pub:
            assert pub.partition == Partition(2, TILE)  # discovered from the servers
            for d in deltas:
                assert pub.send(d.layers, d.t)
                ref.ingest([(delta_key(MAP, "s1"), encode(pub.publisher.build(d.layers, d.t, d.seq)))])
            assert pub.wait_acked(20)
            sent = pub.stats()["sent_per_shard"]
        assert all(n > 0 for n in sent) and sum(sent) > len(deltas)  # both shards fed; some deltas split
        # each shard holds only its own tiles, together exactly the reference map
        part = Partition(2, TILE)
        for i, svc in enumerate(services):
            grid = svc.map.grids["slip"]
            assert grid.tiles and all(
                int(part.shard_of_tiles(np.array(tx), np.array(ty))) == i for tx, ty in grid.tiles
            )
        grid = query_region(client, MAP, (0.0, 0.0, 40.0, 4.0), ClientConfig(connect=(router,)))
        box = (grid.ix0, grid.iy0, grid.ix0 + grid.w - 1, grid.iy0 + grid.h - 1)
        region = ref.map.region(*box, ("slip", "cot"), ("all",))
        for layer in ("slip", "cot"):
            for stat, want in region[layer].items():
                np.testing.assert_allclose(grid.layers[layer][stat], want, equal_nan=True)
        st = get_status(client, MAP)
        assert st is not None and st.shards == 2 and st.shard is None
        assert (st.merged, st.cells) == (sum(sent), ref.map.cells)
        assert st.scouts["s1"].last_seq == sum(sent) - 1 and st.health["shards_answered"] == 2
        # the map's extent: the union of the shards' own (each shard holds only its tiles' cells)
        parts = get_statuses(client, MAP)
        assert st.bounds == ref.map.bounds() and len(parts) == 2
        for p in parts:  # each shard's own box lies inside the map's
            assert p.bounds is not None and st.bounds is not None
            (ax0, ay0, ax1, ay1), (bx0, by0, bx1, by1) = st.bounds, p.bounds
            assert ax0 <= bx0 <= bx1 <= ax1 and ay0 <= by0 <= by1 <= ay1
        # every tile the walk touched was announced, by the shard that owns it
        seen: dict[tuple[int, int], int | None] = {}
        deadline = time.monotonic() + 5
        want_tiles = {
            (int(x) // TILE, int(y) // TILE)
            for d in deltas
            for x, y in zip(d.layers["slip"]["ix"], d.layers["slip"]["iy"], strict=True)
        }
        while set(seen) != want_tiles and time.monotonic() < deadline:
            for ch in watch.changed(0.5):
                for tx, ty in ch.tiles.tolist():
                    seen[(tx, ty)] = ch.shard
        assert set(seen) == want_tiles
        assert all(int(part.shard_of_tiles(np.array(t[0]), np.array(t[1]))) == s for t, s in seen.items())
        assert watch.versions.keys() == {0, 1}


def test_a_misrouted_delta_is_rejected_and_merges_nothing(router, tmp_path):
    with shards(router, tmp_path) as (services, client):
        d = make_delta(seq=0, scout="s2", cells=((0, 0), (9, 0)), layers=("slip",))  # tiles of both shards
        client.put(delta_key(MAP, "s2", 0), encode(d))
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            parts = get_statuses(client, MAP)
            if aggregate_status(parts).rejected:
                break
            time.sleep(0.05)
        st = aggregate_status(get_statuses(client, MAP))
        assert st.rejected == {"wrong_shard": 1} and st.cells == 0 and st.merged == 0


def test_a_sharded_server_needs_its_shard():
    with pytest.raises(ValueError, match="0..1"):
        ServerConfig(map_id=MAP, shards=2)
    with pytest.raises(ValueError, match="0..1"):
        ServerConfig(map_id=MAP, shards=2, shard=2)
    with pytest.raises(ValueError, match="shards=K > 1"):
        ServerConfig(map_id=MAP, shard=1)


def test_a_shard_killed_with_sigkill_recovers_and_nothing_is_lost_or_doubled(tmp_path, procs):
    """Two shard processes; shard 1 is killed with -9 mid-walk and restarted from its SQLite file; the scout
    resends what that shard never acknowledged; the fanned-out map equals one server's merge of the walk."""
    ep = free_endpoint()
    router = spawn("router", "--listen", ep)
    procs.append(router)
    wait_line(router, "router")

    def shard(i: int):
        p = spawn("server", "--map", MAP, "--res", str(RES), "--tile", str(TILE), "--db", str(tmp_path / f"s{i}.db"),
                  "--connect", ep, "--shards", "2", "--shard", str(i))  # fmt: skip
        procs.append(p)
        wait_line(p, "server")
        return p

    servers = [shard(0), shard(1)]
    deltas = walk(60)
    ref = TiledMap(RES, TILE)
    with (
        zenoh.open(zenoh_config(connect=[ep], mode="client")) as client,
        ScoutPublisher(MAP, "s1", RES, [ep], outbox=None, resend_after_s=0.5) as pub,
    ):
        assert pub.partition == Partition(2, TILE)
        for i, d in enumerate(deltas):
            assert pub.send(d.layers, d.t)
            ref.merge(d.layers)
            pub.poll()
            time.sleep(0.01)
            if i == 20:
                servers[1].send_signal(signal.SIGKILL)
                servers[1].wait()
            if i == 40:
                servers[1] = shard(1)
        assert pub.wait_acked(30)
        assert pub.stats()["resent"] > 0  # the kill forced resends
        sent = pub.stats()["sent_per_shard"]
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            st = get_status(client, MAP)
            if st is not None and st.health["shards_answered"] == 2 and st.merged == sum(sent):
                break
            time.sleep(0.05)
        assert st is not None and st.merged == sum(sent) and not st.rejected
        grid = query_region(client, MAP, (0.0, 0.0, 60.0, 4.0), ClientConfig(connect=(ep,)))
        box = (grid.ix0, grid.iy0, grid.ix0 + grid.w - 1, grid.iy0 + grid.h - 1)
        expect = ref.region(*box, ("slip", "cot"), ("all",))
        for layer, stats in expect.items():
            for stat, want in stats.items():
                np.testing.assert_allclose(
                    grid.layers[layer][stat], want, equal_nan=True, err_msg=f"{layer}.{stat}"
                )


def test_a_watching_planner_replans_only_when_its_corridor_changes_on_any_shard(router, tmp_path):
    """`psrmap plan --watch` (component.watch_plan) on a 2-shard map: one plan at the start; deltas far from
    the corridor (other tiles, either shard) cost no replan; a delta inside it — on whichever shard owns
    that tile — triggers exactly the replan that sees it."""
    import threading

    from consumer_planner.component import MapSource, PlanConfig, watch_plan

    delta = plannable_delta

    part = Partition(2, TILE)
    # corridor (0, 0)-(3, 0.8) with 0.4 m margin: cells -1..8 x -1..3, tiles (-1..1, -1..0)
    cfg = PlanConfig(MapSource(map_id=MAP, connect=(router,), margin_m=0.4), (0.0, 0.0), (3.0, 0.8))
    plans: list[tuple[object, object, list]] = []
    stop = threading.Event()
    with shards(router, tmp_path) as (_, client):
        with ScoutPublisher(MAP, "s1", RES, [router], outbox=None) as pub:
            first = delta(0, [(2, 1), (3, 1)])
            assert pub.send(first.layers, first.t) and pub.wait_acked(10)
            out: list = []
            t = threading.Thread(
                target=lambda: out.append(watch_plan(cfg, lambda *a: plans.append(a), stop, resync_s=60.0,
                                                     period_s=0.05)),
                daemon=True,
            )  # fmt: skip
            t.start()
            try:
                deadline = time.monotonic() + 10
                while not plans and time.monotonic() < deadline:
                    time.sleep(0.05)
                # far away: 40 tiles east and north, on both shards
                far = [(400 + 8 * k, 400 + 8 * (k % 3)) for k in range(6)]
                assert {int(part.shard_of(np.array(x), np.array(y))) for x, y in far} == {0, 1}
                for k, cell in enumerate(far, start=1):
                    d = delta(k, [cell])
                    assert pub.send(d.layers, d.t)
                assert pub.wait_acked(10)
                time.sleep(1.0)  # 20 periods of the watch
                n_after_far = len(plans)
                near = delta(7, [(5, 2)])
                assert pub.send(near.layers, near.t) and pub.wait_acked(10)
                deadline = time.monotonic() + 5
                while len(plans) < 2 and time.monotonic() < deadline:
                    time.sleep(0.05)
            finally:
                stop.set()
                t.join(timeout=20)
    assert n_after_far == 1, [p[2] for p in plans]  # the first plan only: far changes were ignored
    assert len(plans) == 2 and plans[1][1] is None and plans[1][0] is not None
    owner = int(part.shard_of(np.array(5), np.array(2)))
    changed = {(c.shard, tuple(x)) for c in plans[1][2] for x in c.tiles.tolist()}
    assert (owner, (0, 0)) in changed  # the notice came from the shard owning cell (5, 2)'s tile
    res = out[0]
    assert (res.plans, res.failed, res.resyncs) == (2, 0, 0) and res.changes_in_box >= 1
