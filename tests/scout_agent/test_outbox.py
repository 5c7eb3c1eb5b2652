"""Issue 12: a scout's unacknowledged deltas survive its own crash (kill -9) while the server is down, and
`--resume` delivers them under their original epoch — 0 lost, 0 doubled."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal

import numpy as np
import pytest
from helpers import InMemoryTransport

from map_server.service import MapService, ServerConfig
from protocol.testing import MAP, RES, make_delta
from psrmap_common.query import wait_for_server
from scout_agent.delivery import DeltaPublisher
from scout_agent.outbox import SQLiteOutbox

N_BEFORE_KILL = 30
N_AFTER = 10


def _delta(i: int):
    return make_delta(seq=i, scout="s1", cells=((i % 7, i // 7),), layers=("slip",), seed=i)


def _scout_then_hang(router: str, outbox: str, started: mp.Event) -> None:
    """Child: publish N_BEFORE_KILL deltas while no server listens, then wait to be killed."""
    from scout_agent.publisher import ScoutPublisher

    pub = ScoutPublisher(MAP, "s1", RES, [router], outbox=outbox)
    for i in range(N_BEFORE_KILL):
        d = _delta(i)
        pub.send(d.layers, d.t)
    started.set()
    signal.pause()


def test_outbox_forgets_only_what_is_acked(tmp_path):
    box = SQLiteOutbox(tmp_path / "o.db")
    pub = DeltaPublisher(InMemoryTransport(), MAP, "s1", RES, epoch=3, outbox=box)
    for i in range(5):
        d = _delta(i)
        pub.send(d.layers, d.t)
    from protocol.messages import Ack

    pub.on_ack(Ack(MAP, "s1", 3, 2))
    assert [s for s, _ in box.pending()[3]] == [3, 4]
    # a new publisher resuming from it resends those two under epoch 3, and its own under a new epoch
    t = InMemoryTransport()
    pub2 = DeltaPublisher(t, MAP, "s1", RES, epoch=4, outbox=box, resume=box.pending())
    assert pub2.unacked == 2 and pub2.resend_all() == 2
    assert pub2.on_ack(Ack(MAP, "s1", 3, 4)) == 2 and pub2.unacked == 0 and box.pending() == {}
    with pytest.raises(ValueError, match="new epoch"):
        DeltaPublisher(t, MAP, "s1", RES, epoch=5, resume={5: [(0, b"x")]})


def test_kill_9_with_the_server_down_then_resume_loses_nothing(router, tmp_path):
    from scout_agent.publisher import ScoutPublisher

    outbox = str(tmp_path / "s1.outbox.db")
    ctx = mp.get_context("spawn")
    started = ctx.Event()
    child = ctx.Process(target=_scout_then_hang, args=(router, outbox, started))
    child.start()
    try:
        assert started.wait(60)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.join(10)
    assert sum(len(v) for v in SQLiteOutbox(outbox).pending().values()) == N_BEFORE_KILL
    with pytest.raises(ValueError, match="--resume"):  # never silently abandoned
        ScoutPublisher(MAP, "s1", RES, [router], outbox=outbox)
    cfg = ServerConfig(map_id=MAP, res=RES, db=str(tmp_path / "m.db"), connect=(router,))
    with MapService(cfg) as service:
        import zenoh

        from psrmap_common.session import zenoh_config

        with zenoh.open(zenoh_config(connect=[router], mode="client")) as client:
            assert wait_for_server(client, MAP)
        with ScoutPublisher(MAP, "s1", RES, [router], outbox=outbox, resume=True) as pub:
            assert pub.resumed == N_BEFORE_KILL
            for i in range(N_BEFORE_KILL, N_BEFORE_KILL + N_AFTER):
                d = _delta(i)
                pub.send(d.layers, d.t)
            assert pub.wait_acked(20)
        st = service.status()
        assert st.merged == N_BEFORE_KILL + N_AFTER and st.duplicates >= 0
        want = sum(float(_delta(i).layers["slip"]["n"].sum()) for i in range(N_BEFORE_KILL + N_AFTER))
        assert service.map.totals()["slip"]["n"] == want  # 0 lost, 0 doubled
        epochs = {e for (s, e) in service.merger.book.seqs if s == "s1"}
        assert len(epochs) == 2  # the crashed run's epoch, then a new one
    assert SQLiteOutbox(outbox).pending() == {}
    assert np.isfinite(want)
