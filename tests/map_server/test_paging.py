"""A map bigger than memory: a server with a tile budget a quarter of its map keeps the rest in SQLite, merges
and answers exactly, and restarts from its file with the same totals."""

from __future__ import annotations

import numpy as np
import pytest
import zenoh

from map_server.errors import MapServerConfigError
from map_server.service import MapService, ServerConfig
from protocol.messages import RegionQuery
from protocol.testing import MAP, RES, make_delta
from psrmap_common.query import wait_for_server
from psrmap_common.session import zenoh_config
from psrmap_mapcore import TiledMap
from scout_agent.delivery import DeltaPublisher
from scout_agent.publisher import ScoutLink, ZenohTransport

TILE = 8


def deltas(n: int) -> list:
    """A scout sweeping a 64 × 40-cell area (8 × 5 tiles of 8 cells) twice: every tile is revisited after the
    others were merged, so it must be paged back in."""
    out = []
    for i in range(n):
        k = i % 80
        x0, y0 = (k % 8) * 8 + (i // 80), (k // 8) * 4
        cells = tuple((x0 + dx, y0 + dy) for dx in range(2) for dy in range(2))
        out.append(make_delta(seq=i, scout="s1", cells=cells, layers=("slip", "cot", "elevation"), seed=i))
    return out


def test_a_map_four_times_its_budget_merges_and_answers_exactly(router, tmp_path):
    ds = deltas(160)
    ref = TiledMap(RES, TILE)
    for d in ds:
        ref.merge(d.layers)
    budget_mib = ref.nbytes() / 4 / 2**20
    db = str(tmp_path / "big.db")
    cfg = ServerConfig(map_id=MAP, res=RES, tile=TILE, db=db, connect=(router,), tile_budget_mib=budget_mib)
    rq = RegionQuery(0.0, 0.0, 30.0, 20.0, None, ("all",))

    def check(service: MapService) -> None:
        assert service.map.nbytes() <= budget_mib * 2**20  # the hot tiles stay within the budget
        assert len(service.pager.cold) >= 20  # most of the 40 tiles live only in the file
        st = service.status()
        assert st.cells == ref.cells and st.merged == len(ds)
        # the extent holds every cell with data; paged-out tiles count whole, so it is exact to within a tile
        (ax0, ay0, ax1, ay1), (bx0, by0, bx1, by1) = st.bounds, ref.bounds()
        assert (
            bx0 - TILE < ax0 <= bx0
            and by0 - TILE < ay0 <= by0
            and bx1 <= ax1 < bx1 + TILE
            and by1 <= ay1 < by1 + TILE
        )
        got = service.region(rq)
        want = ref.region(got.ix0, got.iy0, got.ix0 + got.w - 1, got.iy0 + got.h - 1, stats=("all",))
        for layer in ("slip", "cot", "elevation"):
            for stat, a in want[layer].items():
                np.testing.assert_allclose(
                    got.layers[layer][stat], a, equal_nan=True, err_msg=f"{layer}.{stat}"
                )

    with MapService(cfg) as service, zenoh.open(zenoh_config(connect=[router], mode="client")) as client:
        assert wait_for_server(client, MAP)
        pub = DeltaPublisher(ZenohTransport(client), MAP, "s1", RES, resend_after_s=30, max_unacked=4096)
        with ScoutLink(client, pub) as link:
            assert link.server_up.wait(5)
            for d in ds:
                pub.send(d.layers, d.t)
            assert pub.wait_acked(30)
        check(service)
        assert (
            service.pager.paged_in > 0 and service.pager.evicted > 0
        )  # the second sweep paged tiles back in
    with MapService(cfg) as service:  # restarted from its file, under the same budget
        check(service)


def test_a_budget_needs_a_database_file():
    with pytest.raises(MapServerConfigError, match="--db"):
        MapService(ServerConfig(map_id=MAP, tile_budget_mib=1.0))
