"""Per-cell sufficient statistics on the scout: what accumulates between deltas, and the scout's own map.

`CellAccumulator` buffers per-sample statistics cheaply (one tuple append per `add`) and reduces them per
cell at `flush()` into the `layers` dict of a `CellDelta` (docs/design.md, wire contract: `ix`, `iy` int32 and
float64 stats, a cell at most once per layer). `LocalMap` merges such dicts into the map core's `TiledMap`,
the server's own storage and merge, so a scout with no server holds, cell for cell, what a server would
merge from the same deltas; `save_npz` writes it with `psrmap_mapcore.npz` in the `map_region` layout.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from protocol.layers import (
    LAYERS,
    cell_center,
    cell_index,
    empty_value,
    get_layer,
    merge_op,
    pack_pair,
    unpack_pairs,
)
from psrmap_mapcore import LayerGrid, TiledMap, write_npz
from scout_agent.errors import ScoutConfigError

__all__ = ["CellAccumulator", "LocalMap"]

LayersDict = dict[str, dict[str, np.ndarray]]


class CellAccumulator:
    """Statistics gathered since the last `flush`, per layer; `res` cell size [m], (x0, y0) map origin [m]."""

    def __init__(self, res: float, x0: float = 0.0, y0: float = 0.0) -> None:
        if not res > 0:
            raise ScoutConfigError(f"res={res}; need a cell size > 0 [m]")
        self.res, self.x0, self.y0 = float(res), float(x0), float(y0)
        self._order = {name: layer.stats for name, layer in LAYERS.items()}
        self._ident = {name: tuple(empty_value(s) for s in st) for name, st in self._order.items()}
        self._rows: dict[str, list[tuple[float, ...]]] = {name: [] for name in LAYERS}

    def add(self, layer: str, x: float, y: float, **stats: float) -> None:
        """One sample at map position (x, y) [m]; stats not given take their merge identity."""
        order = self._order.get(layer)
        if order is None:
            get_layer(layer)  # raises, naming the layers
            return
        unknown = stats.keys() - set(order)
        if unknown:
            raise ScoutConfigError(
                f"layer {layer!r} has no stat {sorted(unknown)}; stats: {', '.join(order)}"
            )
        ident = self._ident[layer]
        self._rows[layer].append((x, y, *(stats.get(s, ident[i]) for i, s in enumerate(order))))

    def append(self, layer: str, row: tuple[float, ...]) -> None:
        """Hot path: one sample `(x, y, *stats)` with the stats in `LAYERS[layer].stats` order, unchecked."""
        self._rows[layer].append(row)

    def add_elevation(self, x: float, y: float, z: float) -> None:
        """One foothold (x, y, z) [m]: moments relative to its cell centre, plus min/max."""
        ix, iy = cell_index(x, y, self.res, self.x0, self.y0)
        cx, cy = cell_center(ix, iy, self.res, self.x0, self.y0)
        dx, dy = float(x - cx), float(y - cy)
        self._rows["elevation"].append(
            (x, y, 1.0, z, z * z, dx, dy, dx * dx, dy * dy, dx * dy, dx * z, dy * z, z, z)
        )

    @property
    def pending(self) -> int:
        """Samples buffered since the last flush."""
        return sum(len(r) for r in self._rows.values())

    def flush(self) -> LayersDict:
        """Reduce the buffered samples per cell and clear; layers with no sample are left out."""
        out: LayersDict = {}
        for name, rows in self._rows.items():
            if not rows:
                continue
            arr = np.asarray(rows, dtype=np.float64)
            rows.clear()
            out[name] = reduce_cells(
                arr[:, 0], arr[:, 1], arr[:, 2:], self._order[name], self.res, self.x0, self.y0
            )
        return out


def reduce_cells(
    x: np.ndarray, y: np.ndarray, values: np.ndarray, stats: tuple[str, ...], res: float, x0: float, y0: float
) -> dict[str, np.ndarray]:
    """Group samples (k,) at (x, y) with (k, len(stats)) values per cell, each stat by its merge op.

    One sort by cell and one `reduceat` per merge op, whatever the number of stats.
    """
    ix, iy = cell_index(x, y, res, x0, y0)
    keys = pack_pair(ix, iy)  # one int64 per cell
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    values = values[order]
    starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
    uniq = keys[starts]
    ix_cells, iy_cells = unpack_pairs(uniq)
    cells: dict[str, np.ndarray] = {"ix": ix_cells, "iy": iy_cells}
    for op, ufunc in (("add", np.add), ("min", np.minimum), ("max", np.maximum)):
        cols = [j for j, s in enumerate(stats) if merge_op(s) == op]
        if not cols:
            continue
        red = ufunc.reduceat(values[:, cols], starts, axis=0)
        for c, j in enumerate(cols):
            cells[stats[j]] = red[:, c].copy()
    return cells


class LocalMap:
    """A scout's own map: the map core's `TiledMap` (same merge as the server, vectorised) plus the count
    of deltas merged and the scout's view of it (`cells`, `region`, `save_npz`)."""

    def __init__(self, res: float) -> None:
        self.res = float(res)
        self.map = TiledMap(self.res)
        self.merged = 0  # deltas merged

    def merge(self, layers: Mapping[str, Mapping[str, np.ndarray]]) -> None:
        self.map.merge(layers)
        self.merged += 1

    def cells(self, layer: str) -> dict[str, np.ndarray]:
        """All cells of a layer with data as arrays: `ix`, `iy` and every stat (sorted by (iy, ix))."""
        return self.map.layer_cells(layer)

    def bounds(self) -> tuple[int, int, int, int] | None:
        """(ix0, iy0, ix1, iy1) inclusive over all layers, or None when empty."""
        return self.map.bounds()

    def region(self, ix0: int, iy0: int, ix1: int, iy1: int) -> dict[str, dict[str, np.ndarray]]:
        """Dense (h, w) arrays per layer and stat (row = iy − iy0), plus `value`, as in `map_region`: empty
        cells have n = 0, sums 0, and NaN for value, min and max."""
        return self.map.region(ix0, iy0, ix1, iy1, stats=("all", "value"))

    def save_npz(self, path: str | Path, cover: tuple[int, int, int, int] | None = None) -> Path:
        """Write the whole map as a `.npz` in `map_region` layout (`psrmap_mapcore.npz`).

        `cover` (ix0, iy0, ix1, iy1, inclusive): a cell box the saved region must include besides the data."""
        b = self.bounds() or (cover if cover is not None else (0, 0, -1, -1))
        if cover is not None:
            b = (min(b[0], cover[0]), min(b[1], cover[1]), max(b[2], cover[2]), max(b[3], cover[3]))
        ix0, iy0, ix1, iy1 = b
        if ix1 < ix0 or iy1 < iy0:  # an empty map and no cover: an empty box
            return write_npz(path, LayerGrid("local", self.res, 0, 0, 0, 0, {}))
        return write_npz(path, self.map.dense(ix0, iy0, ix1, iy1))
