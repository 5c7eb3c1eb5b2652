"""The client over a real Zenoh session: two tiny `map` queryables play two server shards."""

from __future__ import annotations

import numpy as np
import pytest
import zenoh

from consumer_planner.client import ClientConfig, MapClient
from consumer_planner.errors import PlannerError
from protocol.codec import encode
from protocol.keys import map_key
from protocol.messages import MapRegion
from psrmap_common.session import free_port, zenoh_config


def _shard(ix0: int, n: float, cot: float) -> bytes:
    layers = {"cot": {"work": np.full((2, 3), cot * n), "dist": np.full((2, 3), n), "n": np.full((2, 3), n)}}
    return encode(MapRegion("m1", 0.5, ix0, 0, 3, 2, 7, layers))


@pytest.fixture
def server():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(zenoh_config(listen=[endpoint])) as session:
        yield session, endpoint


def test_region_fans_out_to_all_shards_and_stitches(server):
    session, endpoint = server
    seen: list[str] = []

    def shard(payload):
        def on_query(query):
            seen.append(str(query.parameters))
            query.reply(query.key_expr, payload)

        return on_query

    q1 = session.declare_queryable(map_key("m1"), shard(_shard(0, 2.0, 1.5)))
    q2 = session.declare_queryable(map_key("m1"), shard(_shard(3, 4.0, 2.0)))
    try:
        with MapClient(ClientConfig(connect=(endpoint,), timeout_s=5.0)) as client:
            grid = client.region("m1", (0.0, 0.0, 2.9, 0.9))
    finally:
        q1.undeclare()
        q2.undeclare()
    assert len(seen) == 2 and all("stats=all" in p for p in seen)
    assert (grid.ix0, grid.w, grid.h, grid.version) == (0, 6, 2, 7)
    np.testing.assert_allclose(grid.value("cot")[0], [1.5, 1.5, 1.5, 2.0, 2.0, 2.0])


def test_errors_name_the_problem(server):
    session, endpoint = server
    cfg = ClientConfig(connect=(endpoint,), timeout_s=0.5)
    with MapClient(cfg) as client, pytest.raises(PlannerError, match="no map server answered 'psr/m1/map'"):
        client.region("m1", (0.0, 0.0, 1.0, 1.0))
    q = session.declare_queryable(map_key("m1"), lambda query: query.reply_err(b"bad_value: empty box"))
    try:
        with MapClient(cfg) as client, pytest.raises(PlannerError, match="refused.*empty box"):
            client.region("m1", (0.0, 0.0, 1.0, 1.0))
    finally:
        q.undeclare()
