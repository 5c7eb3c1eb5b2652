"""The map core: a tiled, multi-layer grid of sufficient statistics in pure numpy (no transport).

Each layer keeps a dict of tiles `(tx, ty) -> float64 (S, T*T)` (S = the layer's stats, T = tile
side in cells), created where data lands, so memory follows the visited area. Merging is vectorised:
one `ufunc.at` per tile and merge operation, never a Python loop per cell.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from protocol.errors import ProtocolError
from protocol.layers import LAYERS, Layer, derived_names, empty_value, get_layer, layer_derived, merge_op

__all__ = ["LayerGrid", "TiledMap"]

TileKey = tuple[int, int]


@dataclass
class LayerGrid:
    """One layer's tiles and the row index of each merge operation in a tile's (S, T*T) block."""

    layer: Layer
    tiles: dict[TileKey, np.ndarray]
    add_rows: np.ndarray  # stats rows merged by sum
    min_rows: np.ndarray
    max_rows: np.ndarray
    empty: np.ndarray  # (S, 1) identity of each stat's merge
    n_row: int  # row of the sample count `n`

    @classmethod
    def for_layer(cls, layer: Layer) -> LayerGrid:
        ops = [merge_op(s) for s in layer.stats]
        rows = {
            op: np.array([i for i, o in enumerate(ops) if o == op], dtype=np.intp)
            for op in ("add", "min", "max")
        }
        empty = np.array([[empty_value(s)] for s in layer.stats])
        return cls(layer, {}, rows["add"], rows["min"], rows["max"], empty, layer.stats.index("n"))


class TiledMap:
    """Multi-layer tiled map of merged statistics.

    res: cell size [m]; tile: tile side [cells], a power of two.
    """

    def __init__(self, res: float, tile: int = 64, layers: Iterable[str] | None = None) -> None:
        if tile <= 0 or tile & (tile - 1):
            raise ValueError(f"tile={tile}; need a power of two (e.g. 32, 64, 128)")
        self.res = float(res)
        self.tile = tile
        self.shift = tile.bit_length() - 1
        self.grids = {name: LayerGrid.for_layer(get_layer(name)) for name in (layers or LAYERS)}
        self.occupied: dict[TileKey, np.ndarray] = {}  # (T*T,) bool: cell holds data in some layer
        self.cells = 0  # cells holding any data
        self.dirty: set[tuple[str, int, int]] = set()  # (layer, tx, ty) changed since `clear_dirty`
        self.touched: set[tuple[str, int, int]] = set()  # changed since `take_touched` (visualisation)

    # ------------------------------------------------------------------ merging

    def merge(self, layers: Mapping[str, Mapping[str, np.ndarray]]) -> int:
        """Merge one delta's (or a batch's concatenated) layers; cells may repeat. Returns updates applied."""
        done = 0
        for name, cells in layers.items():
            grid = self.grids.get(name)
            if grid is None:
                raise ProtocolError(
                    "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
                )
            ix = np.asarray(cells["ix"], dtype=np.int64)
            if ix.size == 0:
                continue
            iy = np.asarray(cells["iy"], dtype=np.int64)
            vals = np.stack([np.asarray(cells[s], dtype=np.float64) for s in grid.layer.stats])  # (S, N)
            done += self._merge_layer(name, grid, ix, iy, vals)
        return done

    def merge_many(self, deltas: Sequence[Mapping[str, Mapping[str, np.ndarray]]]) -> int:
        """Merge several deltas at once: their cells are concatenated per layer, then merged together."""
        if len(deltas) == 1:
            return self.merge(deltas[0])
        by_layer: dict[str, list[Mapping[str, np.ndarray]]] = {}
        for d in deltas:
            for name, cells in d.items():
                by_layer.setdefault(name, []).append(cells)
        done = 0
        for name, parts in by_layer.items():
            grid = self.grids.get(name)
            if grid is None:
                raise ProtocolError(
                    "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
                )
            ix = np.concatenate([np.asarray(p["ix"], dtype=np.int64) for p in parts])
            if ix.size == 0:
                continue
            iy = np.concatenate([np.asarray(p["iy"], dtype=np.int64) for p in parts])
            vals = np.stack(
                [
                    np.concatenate([np.asarray(p[s], dtype=np.float64) for p in parts])
                    for s in grid.layer.stats
                ]
            )
            done += self._merge_layer(name, grid, ix, iy, vals)
        return done

    def merge_columns(self, name: str, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray) -> int:
        """Merge one layer's cells given as columns: ix, iy (N,), vals (S, N) in the layer's stat order."""
        grid = self.grids.get(name)
        if grid is None:
            raise ProtocolError(
                "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
            )
        if not ix.size:
            return 0
        return self._merge_layer(name, grid, ix.astype(np.int64), iy.astype(np.int64), vals)

    def _merge_layer(
        self, name: str, grid: LayerGrid, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray
    ) -> int:
        sh, mask, cells = self.shift, self.tile - 1, self.tile * self.tile
        tx, ty = ix >> sh, iy >> sh  # arithmetic shift = floor division, also for negative indices
        local = ((iy & mask) << sh) | (ix & mask)
        tkey = (tx << 32) | (ty & 0xFFFFFFFF)
        if tkey.size and (tkey[0] == tkey).all():
            segments = [(int(tx[0]), int(ty[0]), slice(None))]
        else:
            order = np.argsort(tkey, kind="stable")
            tkey, tx, ty, local, vals = tkey[order], tx[order], ty[order], local[order], vals[:, order]
            starts = np.flatnonzero(np.r_[True, tkey[1:] != tkey[:-1]])
            ends = np.r_[starts[1:], tkey.size]
            segments = [(int(tx[s]), int(ty[s]), slice(s, e)) for s, e in zip(starts, ends, strict=True)]
        for kx, ky, sl in segments:
            data = grid.tiles.get((kx, ky))
            if data is None:
                data = np.repeat(grid.empty, cells, axis=1)  # (S, T*T)
                grid.tiles[(kx, ky)] = data
            loc = local[sl]
            v = vals[:, sl]
            flat = data.reshape(-1)
            for rows, ufunc in (
                (grid.add_rows, np.add),
                (grid.min_rows, np.minimum),
                (grid.max_rows, np.maximum),
            ):
                if rows.size == 1:
                    r = int(rows[0])
                    ufunc.at(data[r], loc, v[r])
                elif rows.size:
                    idx = (rows[:, None] * cells + loc[None, :]).reshape(-1)
                    ufunc.at(flat, idx, v[rows].reshape(-1))
            occ = self.occupied.get((kx, ky))
            if occ is None:
                occ = np.zeros(cells, dtype=bool)
                self.occupied[(kx, ky)] = occ
            fresh = loc[~occ[loc] & (data[grid.n_row, loc] > 0)]
            if fresh.size:
                fresh = np.unique(fresh)
                occ[fresh] = True
                self.cells += int(fresh.size)
            self.dirty.add((name, kx, ky))
            self.touched.add((name, kx, ky))
        return int(vals.size)

    # ------------------------------------------------------------------ reading

    def region(
        self,
        ix0: int,
        iy0: int,
        ix1: int,
        iy1: int,
        layers: Sequence[str] | None = None,
        stats: Sequence[str] = ("value", "n"),
    ) -> dict[str, dict[str, np.ndarray]]:
        """Stats of the inclusive cell box, per layer: name -> float64 (h, w), row = iy - iy0.

        stats: raw stat names, `value`, derived names (`protocol.layers.layer_derived`), or `all`
        (every raw stat); names a layer lacks are skipped. Empty cells: n = 0, value/min/max = NaN.
        """
        if ix1 < ix0 or iy1 < iy0:
            raise ProtocolError(
                "bad_value", f"empty box [{ix0}..{ix1}] x [{iy0}..{iy1}]; need ix0 <= ix1, iy0 <= iy1"
            )
        names = list(self.grids) if layers is None else list(layers)
        out: dict[str, dict[str, np.ndarray]] = {}
        for name in names:
            grid = self.grids.get(name)
            if grid is None:
                raise ProtocolError(
                    "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
                )
            raw = self._raw_block(grid, ix0, iy0, ix1, iy1)  # (S, h, w)
            by_stat = dict(zip(grid.layer.stats, raw, strict=True))
            want: list[str] = []
            for s in stats:
                if s == "all":
                    want.extend(grid.layer.stats)
                elif s == "value" or s in grid.layer.stats or s in derived_names(name):
                    want.append(s)
            layer_out: dict[str, np.ndarray] = {}
            empty = by_stat["n"] <= 0
            for s in dict.fromkeys(want):
                if s in by_stat and s not in ("value",):
                    a = by_stat[s]
                    if merge_op(s) != "add":
                        a = np.where(empty, np.nan, a)
                    layer_out[s] = a
                else:
                    layer_out[s] = layer_derived(name, s, by_stat)
            out[name] = layer_out
        return out

    def _raw_block(self, grid: LayerGrid, ix0: int, iy0: int, ix1: int, iy1: int) -> np.ndarray:
        T, sh = self.tile, self.shift
        h, w = iy1 - iy0 + 1, ix1 - ix0 + 1
        S = len(grid.layer.stats)
        out = np.empty((S, h, w))
        out[:] = grid.empty[:, :, None]
        if not grid.tiles:
            return out
        for ty in range(iy0 >> sh, (iy1 >> sh) + 1):
            for tx in range(ix0 >> sh, (ix1 >> sh) + 1):
                data = grid.tiles.get((tx, ty))
                if data is None:
                    continue
                cx0, cx1 = max(ix0, tx * T), min(ix1, tx * T + T - 1)
                cy0, cy1 = max(iy0, ty * T), min(iy1, ty * T + T - 1)
                block = data.reshape(S, T, T)
                out[:, cy0 - iy0 : cy1 - iy0 + 1, cx0 - ix0 : cx1 - ix0 + 1] = block[
                    :, cy0 - ty * T : cy1 - ty * T + 1, cx0 - tx * T : cx1 - tx * T + 1
                ]
        return out

    def totals(self) -> dict[str, dict[str, float]]:
        """Per layer, the sum of every additive stat over all cells (for exactness checks)."""
        out: dict[str, dict[str, float]] = {}
        for name, grid in self.grids.items():
            out[name] = {}
            for i, s in enumerate(grid.layer.stats):
                if merge_op(s) == "add":
                    out[name][s] = float(sum(float(t[i].sum()) for t in grid.tiles.values()))
        return out

    def cell_stats(self, layer: str, ix: int, iy: int) -> dict[str, float]:
        """Raw stats of one cell (identity values if it holds no data)."""
        block = self.region(ix, iy, ix, iy, [layer], ["all"])[layer]
        return {s: float(a[0, 0]) for s, a in block.items()}

    def nbytes(self) -> int:
        """Bytes held by tile arrays (statistics + occupancy)."""
        return sum(t.nbytes for g in self.grids.values() for t in g.tiles.values()) + sum(
            o.nbytes for o in self.occupied.values()
        )

    def equals(self, other: TiledMap) -> bool:
        """Same tiles and bit-identical statistics in every layer."""
        if set(self.grids) != set(other.grids):
            return False
        for name, grid in self.grids.items():
            og = other.grids[name]
            if set(grid.tiles) != set(og.tiles):
                return False
            for k, t in grid.tiles.items():
                if not np.array_equal(t, og.tiles[k]):
                    return False
        return True

    # ------------------------------------------------------------------ persistence helpers

    def tile_blob(self, layer: str, tx: int, ty: int) -> bytes:
        return self.grids[layer].tiles[(tx, ty)].astype("<f8", copy=False).tobytes()

    def load_tile(self, layer: str, tx: int, ty: int, blob: bytes) -> None:
        grid = self.grids[layer]
        cells = self.tile * self.tile
        data = np.frombuffer(blob, dtype="<f8").astype(np.float64).reshape(len(grid.layer.stats), cells)
        grid.tiles[(tx, ty)] = data
        n = data[grid.n_row]
        occ = self.occupied.setdefault((tx, ty), np.zeros(cells, dtype=bool))
        before = int(np.count_nonzero(occ))
        occ |= n > 0
        self.cells += int(np.count_nonzero(occ)) - before

    def take_touched(self) -> set[tuple[str, int, int]]:
        touched, self.touched = self.touched, set()
        return touched

    def clear_dirty(self) -> set[tuple[str, int, int]]:
        dirty, self.dirty = self.dirty, set()
        return dirty
