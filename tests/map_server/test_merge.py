from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from map_server.limits import Limits
from map_server.merge import Merger
from protocol import encode
from protocol.keys import delta_key
from protocol.messages import CellDelta
from protocol.partition import Partition
from protocol.testing import DELTA_REASONS, MAP, RES, SCOUT, broken, layer_cells, make_delta
from psrmap_mapcore import TiledMap


def merger(
    max_bytes: int = 8 * 1024 * 1024,
    limits: dict | None = None,
    partition: dict | None = None,
    shard: int | None = None,
    bbox: tuple[int, int, int, int] | None = None,
) -> Merger:
    return Merger(
        TiledMap(RES, tile=8),
        MAP,
        limits=Limits(max_message_bytes=max_bytes, **(limits or {})),
        partition=Partition(**partition) if partition else None,
        shard=shard,
        bbox=bbox,
    )


def sample(d: CellDelta) -> tuple[str, bytes]:
    return delta_key(d.map, d.scout), encode(d)


@st.composite
def delta_sets(draw):
    """A few scouts x epochs, each with seqs 0..k, cells spread over several tiles."""
    deltas = []
    n_streams = draw(st.integers(1, 3))
    for k in range(n_streams):
        scout, epoch = f"s{k % 2}", 10 + k
        for seq in range(draw(st.integers(1, 5))):
            cells = draw(
                st.lists(
                    st.tuples(st.integers(-12, 12), st.integers(-12, 12)), min_size=0, max_size=6, unique=True
                )
            )
            layers = draw(
                st.lists(
                    st.sampled_from(["elevation", "slip", "giam", "contacts"]),
                    min_size=1,
                    max_size=3,
                    unique=True,
                )
            )
            seed = draw(st.integers(0, 2**16))
            rng = np.random.default_rng(seed)
            ix = [c[0] for c in cells]
            iy = [c[1] for c in cells]
            deltas.append(
                CellDelta(MAP, scout, epoch, seq, 0.0, RES, {n: layer_cells(n, ix, iy, rng) for n in layers})
            )
    return deltas


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(deltas=delta_sets(), data=st.data())
def test_any_order_with_duplicates_equals_merging_each_once(deltas, data):
    once = merger()
    once.ingest(sample(d) for d in deltas)
    stream = [sample(d) for d in deltas]
    stream += data.draw(st.lists(st.sampled_from(stream), max_size=len(stream) * 2))
    stream = data.draw(st.permutations(stream))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=4)))
    m = merger()
    prev = 0
    for c in [*cuts, len(stream)]:  # arbitrary batch boundaries
        m.ingest(stream[prev:c])
        prev = c
    assert m.map.equals(once.map)
    assert m.book.merged == len(deltas) and m.book.version == len(deltas)
    assert m.book.duplicates == len(stream) - len(deltas)
    assert m.map.cells == once.map.cells
    for (_scout, _epoch), s in m.book.seqs.items():
        assert not s.above  # every stream complete: the high-water mark covers it


def test_out_of_order_acks_are_cumulative_high_water_marks():
    m = merger()
    r = m.ingest([sample(make_delta(seq=2)), sample(make_delta(seq=0))])
    assert r.acks[(SCOUT, 7)].seq == 0
    r = m.ingest([sample(make_delta(seq=1))])
    assert r.acks[(SCOUT, 7)].seq == 2
    r = m.ingest([sample(make_delta(seq=1))])  # a duplicate still gets an ack (the first may be lost)
    assert r.duplicates == 1 and r.acks[(SCOUT, 7)].seq == 2


@pytest.mark.parametrize("reason", DELTA_REASONS)
def test_each_rejection_reason_leaves_the_map_unchanged(reason):
    key, payload, kw = broken(reason)
    m = merger(
        max_bytes=kw.get("max_bytes", 8 * 1024 * 1024),
        limits=kw.get("limits"),
        partition=kw.get("partition"),
        shard=kw.get("shard"),
        bbox=kw.get("bbox"),
    )
    if reason != "oversize":  # a small valid delta first, so "unchanged" is a non-empty map
        m.ingest([sample(make_delta(seq=5, scout="s9", cells=((1, 1),)))])
    snapshot = {n: {k: t.copy() for k, t in g.tiles.items()} for n, g in m.map.grids.items()}
    version, cells = m.book.version, m.map.cells
    r = m.ingest([(key, payload)])
    assert [x[0] for x in r.rejected] == [reason]
    assert m.book.rejected[reason] == 1
    assert (m.book.version, m.map.cells) == (version, cells)
    for n, g in m.map.grids.items():
        assert set(g.tiles) == set(snapshot[n])
        for k, t in g.tiles.items():
            np.testing.assert_array_equal(t, snapshot[n][k])
    assert (SCOUT, 7) not in m.book.seqs  # a rejected delta does not consume its seq


def test_rejection_inside_a_batch_rejects_only_that_delta():
    m = merger()
    good = [sample(make_delta(seq=i)) for i in range(3)]
    key, bad, _ = broken("nonfinite")
    r = m.ingest([good[0], (key, bad), good[1], good[2]])
    assert len(r.accepted) == 3 and m.book.rejected == {"nonfinite": 1}


def test_wrong_map_is_rejected():
    m = Merger(TiledMap(RES), "other-map")
    r = m.ingest([sample(make_delta())])
    assert r.rejected[0][0] == "key_mismatch" and "holds 'other-map'" in r.rejected[0][1]


def test_a_layer_the_map_lacks_rejects_that_delta_only():
    m = Merger(TiledMap(RES, tile=8, layers=["elevation"]), MAP)
    ok = make_delta(seq=0, layers=("elevation",))
    other = make_delta(seq=1, layers=("slip", "elevation"))
    r = m.ingest([sample(ok), sample(other)])
    assert [reason for reason, _ in r.rejected] == ["unknown_layer"]
    assert "map has no layer 'slip'" in r.rejected[0][1]
    assert m.book.merged == 1 and m.map.cells == 3
