from __future__ import annotations

import pytest
from helpers import InMemoryTransport

from protocol import Ack, decode
from protocol.testing import MAP, RES, SCOUT, make_delta
from scout_agent.delivery import DeltaPublisher, UnackedBufferFull


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def publisher(**kw):
    clock = Clock()
    tr = InMemoryTransport()
    return DeltaPublisher(tr, MAP, SCOUT, RES, epoch=5, clock=clock, **kw), tr, clock


def test_seq_numbers_and_cumulative_acks():
    pub, tr, _ = publisher()
    layers = make_delta().layers
    assert [pub.send(layers, t) for t in range(4)] == [0, 1, 2, 3]
    assert [decode(p).seq for _, p in tr.sent] == [0, 1, 2, 3]
    assert {k for k, _ in tr.sent} == {"psr/m1/delta/s1"}
    assert pub.on_ack(Ack(MAP, SCOUT, 5, 1)) == 2 and pub.unacked == 2
    assert pub.on_ack(Ack(MAP, SCOUT, 4, 3)) == 0  # another epoch: not ours
    assert pub.on_ack(Ack(MAP, SCOUT, 5, 3)) == 2 and pub.unacked == 0


def test_bounded_buffer_refuses_instead_of_dropping():
    pub, tr, _ = publisher(max_unacked=2)
    pub.send({}, 0.0)
    pub.send({}, 0.1)
    assert pub.full
    with pytest.raises(UnackedBufferFull, match="max_unacked=2"):
        pub.send({}, 0.2)
    assert pub.next_seq == 2  # no seq burned
    pub.on_ack(Ack(MAP, SCOUT, 5, 0))
    assert pub.send({}, 0.3) == 2


def test_resend_when_ack_overdue_and_when_server_back():
    pub, tr, clock = publisher(resend_after_s=1.0)
    pub.send({}, 0.0)
    clock.t = 0.5
    pub.send({}, 0.5)
    assert pub.poll() == 0
    clock.t = 1.2
    assert pub.poll() == 1  # only seq 0 is overdue
    assert decode(tr.sent[-1][1]).seq == 0
    pub.request_resend()
    assert pub.poll() == 2
    assert [decode(p).seq for _, p in tr.sent[-2:]] == [0, 1]
    pub.on_ack(Ack(MAP, SCOUT, 5, 1))
    clock.t = 10.0
    assert pub.poll() == 0 and pub.resent == 3


def test_resent_payload_is_identical():
    pub, tr, clock = publisher(resend_after_s=0.0)
    pub.send(make_delta().layers, 1.0)
    pub.poll()
    assert tr.sent[0] == tr.sent[1]
