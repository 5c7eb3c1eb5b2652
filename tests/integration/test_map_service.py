"""Loopback integration over a real router: a router process, a map server process (killed with -9 and
restarted mid-stream), two publishing scouts and a hand-made reordered stream; exact totals at the end."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from helpers import spawn, stop, wait_line

from protocol import decode, encode
from protocol.keys import delta_key, map_key, status_key
from protocol.messages import CellDelta, MapRegion, RegionQuery, Status
from protocol.testing import layer_cells
from psrmap_common.query import wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_mapcore import TiledMap
from scout_agent.delivery import DeltaPublisher
from scout_agent.publisher import ScoutLink, ZenohTransport

MAP, RES = "itest", 0.4
LAYERS5 = ("elevation", "slip", "cot", "giim", "giam")
ROOT = Path(__file__).resolve().parents[2]


def get_one(session, selector: str, timeout_s: float = 10.0) -> bytes:
    """The single reply to `selector`; retries while the route to a just-started queryable settles."""
    deadline = time.monotonic() + timeout_s
    while True:
        replies = list(session.get(selector, timeout=timeout_s))
        if replies or time.monotonic() > deadline:
            break
        threading.Event().wait(0.02)
    assert replies and replies[0].ok is not None, replies and replies[0].err.payload.to_bytes()
    return replies[0].ok.payload.to_bytes()


def scout_layers(k: int, i: int) -> dict:
    rng = np.random.default_rng(1000 * k + i)
    ix = np.arange(20) + i % 7 + 60 * k  # scouts overlap: cells are shared across scouts and deltas
    iy = np.full(20, (i // 7) % 5 - 2)
    return {name: layer_cells(name, ix, iy, rng) for name in LAYERS5}


def test_two_scouts_duplicates_reordering_kill9_restart_exact_totals(tmp_path, procs):
    ep = free_endpoint()
    db = str(tmp_path / "map.db")
    server_args = ("server", "--map", MAP, "--res", str(RES), "--db", db, "--connect", ep)
    router = spawn("router", "--listen", ep)
    procs.append(router)
    wait_line(router, "router")
    server = spawn(*server_args)
    procs.append(server)
    wait_line(server, "server")

    reference = TiledMap(RES)
    with (
        zenoh.open(zenoh_config(connect=[ep], mode="client")) as sa,
        zenoh.open(zenoh_config(connect=[ep], mode="client")) as sb,
    ):
        pubs = [
            DeltaPublisher(ZenohTransport(s), MAP, f"scout{k}", RES, resend_after_s=1.0, max_unacked=1000)
            for k, s in enumerate((sa, sb))
        ]
        links = [ScoutLink(s, p) for s, p in zip((sa, sb), pubs, strict=True)]
        assert all(link.server_up.wait(10) for link in links)
        sent_payloads: list[tuple[str, bytes]] = []
        n_steps = 60
        for i in range(n_steps):
            for k, pub in enumerate(pubs):
                layers = scout_layers(k, i)
                reference.merge(layers)
                pub.send(layers, float(i))
                sent_payloads.append((pub.key, encode(pub.build(layers, float(i), pub.next_seq - 1))))
                pub.poll()
            if i == 25:  # kill -9 in the middle of the stream ...
                server.send_signal(signal.SIGKILL)
                server.wait()
            if i == 40:  # ... and bring it back: scouts resend what was never acknowledged
                server = spawn(*server_args)
                procs.append(server)
                wait_line(server, "server")
        # duplicates of deltas that were already acknowledged
        for key, payload in sent_payloads[:10]:
            sa.put(key, payload)
        # a third, hand-made stream arriving out of order and with duplicates
        manual = []
        for seq in range(6):
            layers = {
                "slip": layer_cells("slip", np.arange(5) - 30, np.full(5, seq), np.random.default_rng(seq))
            }
            reference.merge(layers)
            manual.append(encode(CellDelta(MAP, "manual", 1, seq, 0.0, RES, layers)))
        for seq in (3, 1, 0, 5, 1, 2, 3, 4):
            sa.put(delta_key(MAP, "manual"), manual[seq])

        done = threading.Event()
        deadline = time.monotonic() + 60
        while any(p.unacked for p in pubs) and time.monotonic() < deadline:
            for p in pubs:
                p.poll()
            done.wait(0.05)
        assert not any(p.unacked for p in pubs), [p.unacked for p in pubs]
        total = 2 * n_steps + 6
        while time.monotonic() < deadline:
            st = decode(get_one(sa, status_key(MAP)), expected_type="status")
            assert isinstance(st, Status)
            if st.merged >= total:
                break
            done.wait(0.05)
        assert st.merged == total and st.version == total
        assert (
            st.duplicates >= 2 + 10
        )  # the hand-made duplicates and the replays (plus resends after the kill)
        assert st.scouts["scout0"].last_seq == n_steps - 1 and st.scouts["manual"].last_seq == 5
        assert st.scouts["scout0"].alive and not st.rejected
        assert sum(p.resent for p in pubs) > 0  # the kill did force resends

        def check_exact(session) -> None:
            rq = RegionQuery(-40.0, -3.0, 60.0, 5.0, None, ("all",))
            region = decode(
                get_one(session, f"{map_key(MAP)}?{rq.to_parameters()}"), expected_type="map_region"
            )
            assert isinstance(region, MapRegion)
            expect = reference.region(
                region.ix0, region.iy0, region.ix0 + region.w - 1, region.iy0 + region.h - 1, stats=("all",)
            )
            assert region.layers.keys() == expect.keys()
            for name, stats in expect.items():
                for s, a in stats.items():
                    np.testing.assert_array_equal(region.layers[name][s], a, err_msg=f"{name}.{s}")
            assert int(np.count_nonzero(region.layers["slip"]["n"] > 0)) > 0

        check_exact(sa)
        for link in links:
            link.close()

        # a clean stop, then the database reopens exactly in a new server
        assert stop(server, signal.SIGTERM) == 0
        server = spawn(*server_args)
        procs.append(server)
        wait_line(server, "server")
        assert wait_for_server(sa, MAP)
        check_exact(sa)
        assert stop(server, signal.SIGINT) == 0
    assert stop(router, signal.SIGTERM) == 0
