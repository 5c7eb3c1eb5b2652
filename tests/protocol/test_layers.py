from __future__ import annotations

import numpy as np
import pytest

from protocol import (
    LAYERS,
    ProtocolError,
    cell_center,
    cell_index,
    elevation_slope_deg,
    layer_value,
    merge_op,
    plane_fit,
)
from protocol.layers import MIN_COT_DIST_M, layer_derived


def elevation_stats(x, y, z) -> dict[str, np.ndarray]:
    one = lambda v: np.array([v], dtype=float)  # noqa: E731
    return {
        "n": one(len(z)),
        "sum": one(z.sum()),
        "sumsq": one((z * z).sum()),
        "sx": one(x.sum()),
        "sy": one(y.sum()),
        "sxx": one((x * x).sum()),
        "syy": one((y * y).sum()),
        "sxy": one((x * y).sum()),
        "sxz": one((x * z).sum()),
        "syz": one((y * z).sum()),
        "min": one(z.min()),
        "max": one(z.max()),
    }


def test_layers_and_merge_rule():
    assert list(LAYERS)[:6] == ["elevation", "slip", "cot", "giim", "giam", "contacts"]
    assert "hazard" in LAYERS  # contract extensions follow the six layers of the paper
    assert LAYERS["contacts"].stats == ("n", "nonfoot")
    assert LAYERS["hazard"].stats == ("n", "slip", "margin", "contact", "attitude")
    assert [merge_op(s) for s in ("n", "min", "min_z", "max", "max_v", "minimum")] == [
        "add",
        "min",
        "min",
        "max",
        "max",
        "add",
    ]
    for layer in LAYERS.values():
        assert "n" in layer.stats and set(layer.counts) <= set(layer.stats)


def test_elevation_plane_fit_recovers_plane_and_slope():
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-0.2, 0.2, 40), rng.uniform(-0.2, 0.2, 40)
    z = 2.0 + np.tan(np.radians(20)) * x
    st = elevation_stats(x, y, z)
    assert layer_value("elevation", st)[0] == pytest.approx(2.0)
    assert elevation_slope_deg(st)[0] == pytest.approx(20.0)
    assert layer_derived("elevation", "mean", st)[0] == pytest.approx(z.mean())


def test_elevation_one_track_fits_along_it_only():
    # one straight foot track along y at x = 0.1 on the plane z = 1 + 0.3 x + 0.5 y
    x = np.full(6, 0.1)
    y = np.linspace(-0.15, 0.15, 6)
    z = 1.0 + 0.3 * x + 0.5 * y
    st = elevation_stats(x, y, z)
    z0, gx, gy, rank = plane_fit(st)
    assert rank[0] == 1 and gx[0] == pytest.approx(0.0, abs=1e-12) and gy[0] == pytest.approx(0.5)
    # no cross slope is invented: the centre height is the track's height carried across at zero slope
    assert layer_value("elevation", st)[0] == pytest.approx(z.mean())
    assert elevation_slope_deg(st)[0] == pytest.approx(np.degrees(np.arctan(0.5)))


def test_elevation_clustered_footholds_fall_back_to_mean():
    x = np.array([0.1, 0.1, 0.11, 0.1])  # footholds within a centimetre: no direction is spanned
    y = np.array([0.0, 0.01, 0.0, 0.005])
    z = np.array([1.0, 1.1, 1.2, 1.3])
    st = elevation_stats(x, y, z)
    assert plane_fit(st)[3][0] == 0
    assert layer_value("elevation", st)[0] == pytest.approx(z.mean())
    assert np.isnan(elevation_slope_deg(st)[0])


def test_values_nan_where_no_data_and_cot_threshold():
    assert np.isnan(layer_value("slip", {"n": np.array([0.0]), "events": np.array([0.0])})[0])
    assert layer_value("slip", {"n": np.array([4.0]), "events": np.array([1.0])})[0] == 0.25
    assert layer_derived("slip", "events", {"n": np.array([4.0]), "events": np.array([1.0])})[0] == 1.0
    cot = layer_value(
        "cot",
        {
            "work": np.array([1.0, 1.0]),
            "dist": np.array([MIN_COT_DIST_M / 2, 2.0]),
            "n": np.array([3.0, 3.0]),
        },
    )
    assert np.isnan(cot[0]) and cot[1] == 0.5
    g = {"n": np.array([2.0]), "sum": np.array([0.6]), "sumsq": np.array([0.2]), "min": np.array([0.1])}
    assert layer_value("giim", g)[0] == pytest.approx(0.3)
    assert layer_derived("giam", "worst", g)[0] == 0.1
    assert layer_value("contacts", {"n": np.array([10.0]), "nonfoot": np.array([2.0])})[0] == 0.2
    hz = {k: np.array([0.0, 2.0]) for k in ("n", "slip", "margin", "contact", "attitude")}
    hz["margin"] = np.array([0.0, 1.0])
    v = layer_value("hazard", hz)
    assert np.isnan(v[0]) and v[1] == 2.0  # reports; merged by adding (the generic rule)
    assert layer_derived("hazard", "margin", hz)[1] == 1.0
    assert all(merge_op(s) == "add" for s in LAYERS["hazard"].stats)


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(ProtocolError, match="layers: elevation, slip"):
        layer_value("cots", {})
    with pytest.raises(ProtocolError, match="derived: value, events, rate"):
        layer_derived("slip", "slope_deg", {})


def test_cell_index_floor_and_centre():
    ix, iy = cell_index([-0.01, 0.0, 0.39, 0.4], [1.0, -1.0, 0.0, 0.0], 0.4)
    assert ix.tolist() == [-1, 0, 0, 1] and iy.tolist() == [2, -3, 0, 0] and ix.dtype == np.int32
    x, y = cell_center(ix, iy, 0.4)
    assert x.tolist() == pytest.approx([-0.2, 0.2, 0.2, 0.6])


def test_pack_pair_round_trips_signed_indices_for_ints_and_arrays() -> None:
    from protocol.layers import pack_pair, unpack_pair, unpack_pairs

    pairs = [(0, 0), (-1, 0), (0, -1), (-(2**30), 2**30), (2**31 - 1, -(2**31)), (5, -7)]
    for a, b in pairs:
        assert unpack_pair(pack_pair(a, b)) == (a, b)
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    keys = pack_pair(a, b)
    assert keys.dtype == np.int64 and len(np.unique(keys)) == len(pairs)
    assert [unpack_pair(k) for k in keys.tolist()] == pairs
    ua, ub = unpack_pairs(keys)
    assert ua.dtype == ub.dtype == np.int32 and ua.tolist() == a.tolist() and ub.tolist() == b.tolist()
