"""MapService in-process over a real (embedded) Zenoh router on loopback."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from protocol import decode, encode
from protocol.keys import delta_key, map_key, status_key
from protocol.messages import MapRegion, RegionQuery, Status
from protocol.testing import MAP, RES, broken, make_delta
from scout_agent.delivery import DeltaPublisher
from scout_agent.publisher import ScoutLink, ZenohTransport


@pytest.fixture
def net(served_map):
    with served_map(MAP, RES) as pair:
        yield pair


def get_one(session, selector):
    replies = list(session.get(selector, timeout=5))
    assert len(replies) == 1
    return replies[0]


def test_publish_ack_query_status(net):
    service, client = net
    pub = DeltaPublisher(ZenohTransport(client), MAP, "s1", RES, resend_after_s=30)
    with ScoutLink(client, pub) as link:
        assert link.server_up.wait(5)
        deltas = [
            make_delta(seq=i, scout="s1", cells=((i, 0), (i, 1)), layers=("slip",), seed=i) for i in range(5)
        ]
        for d in deltas:
            pub.send(d.layers, d.t)
        assert pub.wait_acked(10)
        key, bad, _ = broken("wrong_res")
        client.put(key, bad)
        client.put(delta_key(MAP, "s1"), encode(pub.build(deltas[0].layers, deltas[0].t, 0)))  # a duplicate
        region = decode(
            get_one(
                client,
                f"{map_key(MAP)}?{RegionQuery(0, 0, 2.0, 0.4, ('slip',), ('all', 'value')).to_parameters()}",
            ).ok.payload.to_bytes()
        )
        assert isinstance(region, MapRegion) and (region.w, region.h) == (6, 2)
        n = np.array([[d.layers["slip"]["n"][0] for d in deltas] + [0]])
        np.testing.assert_array_equal(region.layers["slip"]["n"][:1], n)
        assert np.isnan(region.layers["slip"]["value"][0, 5])

        done = threading.Event()
        st: Status | None = None
        for _ in range(100):  # the bad and duplicate puts are merged asynchronously
            st = decode(get_one(client, status_key(MAP)).ok.payload.to_bytes())
            if st.duplicates == 1 and st.rejected:
                break
            done.wait(0.05)
        assert isinstance(st, Status)
        assert (st.merged, st.version, st.duplicates, st.rejected, st.cells) == (
            5,
            5,
            1,
            {"wrong_res": 1},
            10,
        )
        assert st.scouts["s1"].epoch == pub.epoch and st.scouts["s1"].last_seq == 4 and st.scouts["s1"].alive


@pytest.mark.parametrize(
    "params, reason",
    [
        ("x0=0;y0=0;x1=1", "missing_field"),
        ("x0=0;y0=0;x1=1;y1=1;layers=cots", "unknown_layer"),
        ("x0=0;y0=0;x1=1;y1=1;stats=vlaue", "unknown_stat"),
        ("x0=a;y0=0;x1=1;y1=1", "wrong_type"),
        ("x0=0;y0=0;x1=-1;y1=1", "bad_value"),
        ("x0=0;y0=0;x1=100000;y1=100000", "limit_query_cells"),
        # issue 12: a box beyond the index range overflowed int32 and answered one cell
        ("x0=-1e300;y0=-1e300;x1=1e300;y1=1e300", "bad_value"),
        # issue 12: repeated layers held the map lock for 30 s
        ("x0=0;y0=0;x1=1;y1=1;layers=" + ",".join(["slip"] * 1000), "duplicate_name"),
        # issue 12: the largest allowed box with every stat made an 823 MiB reply
        ("x0=-390;y0=-390;x1=390;y1=390;stats=all", "limit_reply_bytes"),
    ],
)
def test_bad_query_gets_reply_err_with_reason(net, params, reason):
    _, client = net
    reply = get_one(client, f"{map_key(MAP)}?{params}")
    assert reply.ok is None
    assert reply.err.payload.to_bytes().decode().startswith(reason + ":")


def test_region_query_of_derived_stats(net):
    service, client = net
    service._process([(delta_key(MAP, "s3"), encode(make_delta(scout="s3", layers=("elevation",))))])
    rq = RegionQuery(-2, -1, 1, 3, ("elevation",), ("value", "slope_deg", "min"))
    region = decode(get_one(client, f"{map_key(MAP)}?{rq.to_parameters()}").ok.payload.to_bytes())
    assert set(region.layers["elevation"]) == {"value", "slope_deg", "min"}
