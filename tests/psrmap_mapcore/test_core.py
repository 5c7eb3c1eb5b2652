"""The map core: one implementation used by every service, its import rule, cells, bounds and .npz."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from protocol.layers import LAYERS, merge_op
from protocol.testing import layer_cells
from psrmap_mapcore import LayerGrid, MapFileError, TiledMap, read_npz, write_npz

ROOT = Path(__file__).resolve().parents[2]
SERVICES = ("scout_agent", "map_server", "consumer_planner")


def _imports(package: str) -> dict[str, set[str]]:
    """module path -> top-level packages it imports (absolute imports, at any depth of the module)."""
    out: dict[str, set[str]] = {}
    for path in (ROOT / package).rglob("*.py"):
        tops: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                tops.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                tops.add(node.module.split(".")[0])
        out[str(path.relative_to(ROOT))] = tops
    return out


def test_services_import_protocol_and_the_map_core_never_each_other():
    for service in SERVICES:
        others = set(SERVICES) - {service}
        for module, tops in _imports(service).items():
            assert not tops & others, f"{module} imports {sorted(tops & others)}"


def test_the_shared_path_search_imports_no_service():
    allowed = {"psrmap_common", "numpy", "numba", "skimage", "__future__", "dataclasses", "typing", "math"}
    mods = _imports("psrmap_common/pathsearch")
    assert "psrmap_common/pathsearch/search.py" in mods
    for module, tops in mods.items():
        assert tops <= allowed, f"{module} imports {sorted(tops - allowed)}"


def test_the_map_core_is_pure_numpy_on_the_contract():
    allowed = {"psrmap_mapcore", "protocol", "numpy", "__future__", "collections", "dataclasses", "typing",
               "pathlib", "mmap", "itertools", "math"}  # fmt: skip
    for module, tops in _imports("psrmap_mapcore").items():
        assert tops <= allowed, f"{module} imports {sorted(tops - allowed)}"


def _reference(deltas: list[dict]) -> dict[str, dict[tuple[int, int], np.ndarray]]:
    """Per layer, per cell: the merged stats by the layer table's rule, one cell at a time."""
    out: dict[str, dict[tuple[int, int], np.ndarray]] = {}
    for layers in deltas:
        for name, cells in layers.items():
            stats = LAYERS[name].stats
            table = out.setdefault(name, {})
            for k, key in enumerate(zip(cells["ix"].tolist(), cells["iy"].tolist(), strict=True)):
                row = np.array([cells[s][k] for s in stats])
                if key not in table:
                    table[key] = row
                    continue
                for c, s in enumerate(stats):
                    op = merge_op(s)
                    cur = table[key]
                    cur[c] = cur[c] + row[c] if op == "add" else (min if op == "min" else max)(cur[c], row[c])
    return out


def _deltas(seed: int, n: int = 30) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        layers = {}
        for name in ("elevation", "slip", "giim"):
            k = int(rng.integers(1, 6))
            flat = rng.choice(400, size=k, replace=False)
            layers[name] = layer_cells(name, flat % 20 - 70, flat // 20 + 63, rng)  # crosses tile borders
        out.append(layers)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_layer_cells_and_bounds_match_a_cell_by_cell_reference(seed):
    deltas = _deltas(seed)
    m = TiledMap(0.4)
    for d in deltas:
        m.merge(d)
    ref = _reference(deltas)
    for name, table in ref.items():
        got = m.layer_cells(name)
        keys = sorted(table, key=lambda k: (k[1], k[0]))
        assert got["ix"].tolist() == [k[0] for k in keys] and got["iy"].tolist() == [k[1] for k in keys]
        for c, s in enumerate(LAYERS[name].stats):
            np.testing.assert_allclose(got[s], [table[k][c] for k in keys])
    every = [k for t in ref.values() for k in t]
    xs, ys = zip(*every, strict=True)
    assert m.bounds() == (min(xs), min(ys), max(xs), max(ys))
    assert TiledMap(0.4).bounds() is None


def test_npz_round_trip_through_the_dense_view(tmp_path):
    m = TiledMap(0.4)
    for d in _deltas(5):
        m.merge(d)
    ix0, iy0, ix1, iy1 = m.bounds()
    grid = m.dense(ix0, iy0, ix1, iy1, map_id="m1")
    back = read_npz(write_npz(tmp_path / "m.npz", grid), map_id="m1")
    assert (back.res, back.ix0, back.iy0, back.h, back.w) == (0.4, ix0, iy0, iy1 - iy0 + 1, ix1 - ix0 + 1)
    for name, stats in grid.layers.items():
        for s, a in stats.items():
            np.testing.assert_array_equal(back.layers[name][s], a)
    assert isinstance(back, LayerGrid) and np.nansum(back.count("slip")) == np.sum(m.layer_cells("slip")["n"])


def test_bad_map_files_name_the_valid_layout(tmp_path):
    with pytest.raises(MapFileError, match="no map file"):
        read_npz(tmp_path / "nope.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(MapFileError, match="not a readable .npz map"):
        read_npz(tmp_path / "junk.npz")
    np.savez(tmp_path / "bare.npz", res=0.4)
    with pytest.raises(MapFileError, match="need res, ix0, iy0 and <layer>/<stat> arrays"):
        read_npz(tmp_path / "bare.npz")
