"""Cell accumulation and the scout's local map: per-cell reduction, merge rule, .npz layout."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import InMemoryTransport
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.codec import decode
from protocol.layers import LAYERS, layer_value
from psrmap_mapcore import read_npz
from scout_agent.cells import CellAccumulator, LocalMap
from scout_agent.delivery import DeltaPublisher


def test_flush_reduces_per_cell_with_each_stats_merge_op():
    acc = CellAccumulator(0.4)
    acc.add("giim", 0.1, 0.1, n=1, sum=0.5, sumsq=0.25, min=0.5)
    acc.add("giim", 0.3, 0.2, n=1, sum=0.3, sumsq=0.09, min=0.3)
    acc.add("giim", -0.1, 0.1, n=1, sum=0.7, sumsq=0.49, min=0.7)
    out = acc.flush()
    assert set(out) == {"giim"}
    g = out["giim"]
    cells = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(g["ix"], g["iy"], strict=True))}
    k = cells[(0, 0)]
    assert g["n"][k] == 2 and g["sum"][k] == pytest.approx(0.8) and g["min"][k] == pytest.approx(0.3)
    assert g["n"][cells[(-1, 0)]] == 1
    assert g["ix"].dtype == np.int32 and g["sum"].dtype == np.float64
    assert acc.flush() == {} and acc.pending == 0


def test_elevation_moments_are_relative_to_the_cell_centre():
    acc = CellAccumulator(0.4)
    acc.add_elevation(0.25, 0.1, 1.0)  # cell (0, 0), centre (0.2, 0.2)
    acc.add_elevation(0.15, 0.3, 2.0)
    e = acc.flush()["elevation"]
    assert e["n"][0] == 2 and e["sum"][0] == 3.0 and e["min"][0] == 1.0 and e["max"][0] == 2.0
    assert e["sx"][0] == pytest.approx(0.0) and e["sy"][0] == pytest.approx(0.0)
    assert e["sxz"][0] == pytest.approx(0.05 * 1 - 0.05 * 2)
    assert e["syz"][0] == pytest.approx(-0.1 * 1 + 0.1 * 2)


def test_unknown_layer_or_stat_is_named():
    acc = CellAccumulator(0.4)
    with pytest.raises(Exception, match="layers: elevation"):
        acc.add("cots", 0, 0, n=1)
    with pytest.raises(ValueError, match="stats: work, dist, n"):
        acc.add("cot", 0, 0, energy=1)


def test_missing_stats_take_their_merge_identity():
    acc = CellAccumulator(0.4)
    acc.add("giam", 0, 0, n=1, sum=1.0, sumsq=1.0)
    g = acc.flush()["giam"]
    assert g["min"][0] == np.inf


def _random_deltas(rng, n_deltas=6):
    acc = CellAccumulator(0.4)
    deltas = []
    for _ in range(n_deltas):
        for _ in range(rng.integers(1, 40)):
            x, y = rng.uniform(-2, 2, 2)
            v = float(rng.normal())
            acc.add("giim", x, y, n=1, sum=v, sumsq=v * v, min=v)
            acc.add("cot", x, y, work=abs(v), dist=0.01, n=1)
            acc.add("slip", x, y, n=1, events=float(rng.random() < 0.2))
            acc.add_elevation(x, y, v)
        deltas.append(acc.flush())
    return deltas


def test_local_map_is_independent_of_order_and_matches_one_big_reduction():
    rng = np.random.default_rng(3)
    deltas = _random_deltas(rng)
    a, b = LocalMap(0.4), LocalMap(0.4)
    for d in deltas:
        a.merge(d)
    for d in reversed(deltas):
        b.merge(d)
    for layer in ("giim", "cot", "slip", "elevation"):
        ca, cb = a.cells(layer), b.cells(layer)
        for s in ca:
            np.testing.assert_allclose(ca[s], cb[s], rtol=1e-12, atol=1e-12)


def test_save_npz_has_the_map_region_layout(tmp_path):
    m = LocalMap(0.4)
    for d in _random_deltas(np.random.default_rng(4)):
        m.merge(d)
    path = m.save_npz(tmp_path / "map.npz")
    grid = read_npz(path)
    header = {"res": grid.res, "ix0": grid.ix0, "iy0": grid.iy0, "w": grid.w, "h": grid.h}
    layers = grid.layers
    ix0, iy0, ix1, iy1 = m.bounds()
    assert header == {"res": 0.4, "ix0": ix0, "iy0": iy0, "w": ix1 - ix0 + 1, "h": iy1 - iy0 + 1}
    for name, layer in LAYERS.items():
        for s in (*layer.stats, "value"):
            assert layers[name][s].shape == (header["h"], header["w"])
    g = m.cells("giim")
    r = g["iy"] - iy0
    c = g["ix"] - ix0
    np.testing.assert_array_equal(layers["giim"]["sum"][r, c], g["sum"])
    np.testing.assert_allclose(layers["giim"]["value"][r, c], layer_value("giim", g))
    empty = layers["giim"]["n"] == 0
    assert np.isnan(layers["giim"]["value"][empty]).all()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_local_map_equals_what_a_server_merges_from_the_same_deltas(seed):
    """The deltas go through the wire codec into map_server's TiledMap; the local map sees the same dicts."""
    from psrmap_mapcore import TiledMap

    rng = np.random.default_rng(seed)
    deltas = _random_deltas(rng, n_deltas=4)
    transport = InMemoryTransport()
    pub = DeltaPublisher(transport, "m1", "s1", 0.4, epoch=1)
    local = LocalMap(0.4)
    for k, d in enumerate(deltas):
        pub.send(d, t=float(k))
        local.merge(d)
    server = TiledMap(0.4)
    for _, payload in transport.sent:
        server.merge(decode(payload, expected_type="cell_delta").layers)
    ix0, iy0, ix1, iy1 = local.bounds()
    mine = local.region(ix0, iy0, ix1, iy1)
    theirs = server.region(ix0, iy0, ix1, iy1, layers=list(LAYERS), stats=["all"])
    for name in ("giim", "cot", "slip", "elevation"):
        for s in LAYERS[name].stats:
            np.testing.assert_allclose(
                np.asarray(theirs[name][s]).reshape(mine[name][s].shape),
                mine[name][s],
                rtol=1e-12,
                atol=1e-12,
            )
