from __future__ import annotations

import numpy as np
import pytest

from protocol import LAYERS, ProtocolError, layer_value
from protocol.testing import layer_cells
from psrmap_mapcore import TiledMap


def dense_reference(parts, name, box):
    """Merge with a plain dict per cell (the obvious, slow implementation)."""
    ix0, iy0, ix1, iy1 = box
    stats = LAYERS[name].stats
    ref = {
        s: np.full((iy1 - iy0 + 1, ix1 - ix0 + 1), {"min": np.inf, "max": -np.inf}.get(s, 0.0)) for s in stats
    }
    for cells in parts:
        for k in range(len(cells["ix"])):
            r, c = cells["iy"][k] - iy0, cells["ix"][k] - ix0
            for s in stats:
                if s == "min":
                    ref[s][r, c] = min(ref[s][r, c], cells[s][k])
                elif s == "max":
                    ref[s][r, c] = max(ref[s][r, c], cells[s][k])
                else:
                    ref[s][r, c] += cells[s][k]
    return ref


@pytest.mark.parametrize("tile", [4, 64])
def test_merge_matches_reference_across_tiles_and_negative_indices(tile):
    rng = np.random.default_rng(3)
    m = TiledMap(0.4, tile=tile)
    parts = []
    for _ in range(6):
        flat = rng.choice(40 * 30, size=50, replace=False)
        ix, iy = flat % 40 - 20, flat // 40 - 15
        parts.append(layer_cells("elevation", ix, iy, rng))
    m.merge_many([{"elevation": p} for p in parts[:3]])
    for p in parts[3:]:
        m.merge({"elevation": p})
    box = (-20, -15, 19, 14)
    got = m.region(*box, layers=["elevation"], stats=["all", "value"])["elevation"]
    ref = dense_reference(parts, "elevation", box)
    empty = ref["n"] == 0
    for s in LAYERS["elevation"].stats:
        expect = np.where(empty, np.nan, ref[s]) if s in ("min", "max") else ref[s]
        np.testing.assert_array_equal(got[s], expect)
    np.testing.assert_allclose(got["value"], layer_value("elevation", ref), equal_nan=True)
    assert m.cells == int(np.count_nonzero(~empty))


def test_empty_cells_are_nan_and_tiles_only_where_data_lands():
    m = TiledMap(0.4)
    m.merge(
        {
            "slip": {
                "ix": np.array([1000, -1000], np.int32),
                "iy": np.array([5, -5], np.int32),
                "n": np.array([2.0, 1.0]),
                "events": np.array([1.0, 0.0]),
            }
        }
    )
    assert len(m.grids["slip"].tiles) == 2 and not m.grids["elevation"].tiles
    r = m.region(999, 4, 1001, 6, ["slip", "elevation"], ["value", "n", "events"])
    assert r["slip"]["value"][1, 1] == 0.5 and np.isnan(r["slip"]["value"][0, 0])
    assert r["slip"]["n"][0, 0] == 0 and r["slip"]["events"][1, 1] == 1.0
    assert np.isnan(r["elevation"]["value"]).all() and "events" not in r["elevation"]
    assert m.cells == 2


def test_region_errors_name_valid_choices():
    m = TiledMap(0.4)
    with pytest.raises(ProtocolError, match="layers: elevation, slip"):
        m.region(0, 0, 1, 1, ["cots"])
    with pytest.raises(ProtocolError, match="ix0 <= ix1"):
        m.region(2, 0, 1, 1)
    with pytest.raises(ValueError, match="power of two"):
        TiledMap(0.4, tile=48)


def test_tile_blob_round_trip():
    m = TiledMap(0.4)
    m.merge({"giim": layer_cells("giim", [3, 70], [-2, 9])})
    other = TiledMap(0.4)
    for layer, tx, ty in m.dirty:
        other.load_tile(layer, tx, ty, m.tile_blob(layer, tx, ty))
    assert other.equals(m) and other.cells == m.cells == 2


def _n_at(m: TiledMap, ix: int, iy: int) -> float:
    return float(m.region(ix, iy, ix, iy, ["slip"], ["n"])["slip"]["n"][0, 0])


@pytest.mark.parametrize(
    "order", [[(0, 0), (1400, 1400), (700, 700)], [(0, 0), (1400, 1400), (700, 700), (-900, 5)]]
)
def test_tiles_far_apart_land_in_their_own_place(order):
    """Issue 12: tiles 36–51 km apart (valid indices) broke the dense tile directory: an IndexError that
    stopped the merge worker, or a cell merged into another tile."""
    m = TiledMap(0.4, tile=64)
    cells = []
    for k, (tx, ty) in enumerate(order):
        ix, iy = tx * 64 + 3, ty * 64 + 5
        m.merge(
            {
                "slip": {
                    "ix": np.array([ix], np.int32),
                    "iy": np.array([iy], np.int32),
                    "n": np.array([k + 1.0]),
                    "events": np.array([0.0]),
                }
            }
        )
        cells.append((ix, iy, k + 1.0))
    for ix, iy, n in cells:
        assert _n_at(m, ix, iy) == n
    assert m.cells == len(order)


def test_extreme_valid_indices_merge_and_restore():
    lim = (1 << 30) - 1
    m = TiledMap(0.4, tile=64)
    pts = [(-lim, -lim), (lim, lim), (0, 0), (-lim, lim), (12345, -67890)]
    for k, (ix, iy) in enumerate(pts):
        m.merge(
            {
                "slip": {
                    "ix": np.array([ix], np.int32),
                    "iy": np.array([iy], np.int32),
                    "n": np.array([k + 1.0]),
                    "events": np.array([1.0]),
                }
            }
        )
    for k, (ix, iy) in enumerate(pts):
        assert _n_at(m, ix, iy) == k + 1.0
    # what the store does on restart: tiles loaded one by one from their blobs, in any order
    m2 = TiledMap(0.4, tile=64)
    for name, tx, ty in sorted(m.dirty, reverse=True):
        m2.load_tile(name, tx, ty, m.tile_blob(name, tx, ty))
    assert m2.equals(m)
    for k, (ix, iy) in enumerate(pts):
        assert _n_at(m2, ix, iy) == k + 1.0
